"""clutt3r_viewer.rerun_export and the export-rerun / view / demo commands."""

from __future__ import annotations

from clutt3r_viewer.rerun_export import export_rerun


def test_rrd_is_written_and_non_trivial(tiny_data, tmp_path):
    out = export_rerun(tiny_data, tmp_path / "sub" / "t.rrd", max_points=5000)
    assert out.is_file()
    raw = out.read_bytes()
    assert raw[:4] == b"RRF2" or raw[:3] == b"RRF"
    # images of 4 views + masks + clouds + one colour array per event: well over 100 kB
    assert len(raw) > 100_000
    assert not list(out.parent.glob("*.tmp"))


def test_export_command(tiny_run_dir, tmp_path, capsys):
    from clutt3r_viewer.cli import export_rerun_command

    export_rerun_command(tiny_run_dir, tmp_path / "x.rrd")
    assert (tmp_path / "x.rrd").stat().st_size > 100_000
    assert "grouping events" in capsys.readouterr().out


def test_commands_are_registered_with_the_core_cli():
    from clutt3r_core.cli import available_commands

    cmds = available_commands()
    assert {"view", "export-rerun", "demo"} <= set(cmds)


def test_demo_run_is_written_with_its_scene_linked(tmp_path):
    from clutt3r_viewer.cli import make_demo_run
    from clutt3r_viewer.loading import load_viewer_data

    run = make_demo_run(tmp_path / "demo", seed=1, preset="easy", views=3, width=320, height=240, focal_px=200.0)
    d = load_viewer_data(run)
    from clutt3r_core.runs import read_run_info

    # the scene is linked by run.json now (relative, so run and scene move together), not viewer.json
    assert len(d.views) == 3 and str(read_run_info(run).scene) == "scene" and (run / "instance_tree.json").is_file()
