"""The command line's answer to bad input: one line naming the file and the problem, exit
status 2; ``--debug`` / ``CLUTT3R_DEBUG=1`` add the traceback (issue 14).

The measured cases of issue 14 are here: a truncated PNG (was 20+ traceback lines and an
OpenCV/libpng line), a frame whose depth file is missing (was silently demoted), all-zero
depth maps (was "0 instances", exit 0).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clutt3r_core.cli import USER_ERROR_STATUS, main
from clutt3r_core.io.images import write_png

CLI = [sys.executable, "-m", "clutt3r_core"]


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


def _run(args: list[str], env: dict | None = None) -> subprocess.CompletedProcess:
    e = {k: v for k, v in os.environ.items() if k not in ("CLUTT3R_DEBUG", "OPENCV_LOG_LEVEL")}
    e.update(env or {})
    return subprocess.run(CLI + args, capture_output=True, text=True, env=e, timeout=120)


def _main(args: list[str], capfd) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as ei:
        main(args)
        raise SystemExit(0)
    out, err = capfd.readouterr()
    return ei.value.code, out, err


def test_truncated_png_is_one_line_exit_2(scene_dir, tmp_path):
    bad = scene_dir / "images" / "image_000001.png"
    _truncate(bad)
    r = _run(["segment", str(scene_dir), "--out", str(tmp_path / "run")])
    assert r.returncode == USER_ERROR_STATUS == 2
    assert r.stdout == ""
    # exactly one line on stderr: ours, naming the file and the problem; no libpng/OpenCV line
    assert r.stderr.count("\n") == 1 and r.stderr.endswith("\n"), r.stderr
    assert r.stderr.startswith(f"clutt3r: error: {bad}: corrupt or truncated PNG"), r.stderr
    assert "ends inside its IDAT chunk" in r.stderr
    assert not (tmp_path / "run").exists()


def test_debug_shows_the_traceback(scene_dir, tmp_path):
    _truncate(scene_dir / "depth" / "depth_000002.png")
    r = _run(["--debug", "segment", str(scene_dir), "--out", str(tmp_path / "run")])
    assert r.returncode == 2
    assert "Traceback (most recent call last)" in r.stderr and "SceneFileError" in r.stderr
    last = r.stderr.strip().splitlines()[-1]
    assert last.startswith("clutt3r: error: ") and "depth_000002.png" in last


def test_debug_env_variable_and_flag_after_the_command(scene_dir, tmp_path, capfd, monkeypatch):
    (scene_dir / "transforms.json").write_text("{")
    args = ["segment", str(scene_dir), "--out", str(tmp_path / "r")]
    code, _, err = _main([*args, "--debug"], capfd)
    assert code == 2 and "Traceback" in err and "transforms.json: not valid JSON" in err
    monkeypatch.setenv("CLUTT3R_DEBUG", "1")
    code, _, err = _main(args, capfd)
    assert code == 2 and "Traceback" in err
    monkeypatch.setenv("CLUTT3R_DEBUG", "0")
    code, _, err = _main(args, capfd)
    assert code == 2 and "Traceback" not in err and err.count("\n") == 1


def test_bad_arguments_stay_tyros(capfd, tmp_path):
    code, _, err = _main(["segment", str(tmp_path)], capfd)  # --out is required
    assert code == 2
    assert "Traceback" not in err and "clutt3r: error:" not in err
    assert "--out" in err


def test_missing_scene_folder(capfd, tmp_path):
    code, out, err = _main(["segment", str(tmp_path / "nope"), "--out", str(tmp_path / "r")], capfd)
    assert code == 2 and out == ""
    assert err == f"clutt3r: error: {tmp_path / 'nope'}: scene folder not found\n"


def test_missing_depth_file_demotes_the_frame_with_a_warning(scene_dir, tmp_path, capfd):
    # without clutt3r_scene.json the roles are inferred: a frame without depth is post-interaction
    (scene_dir / "clutt3r_scene.json").unlink()
    (scene_dir / "depth" / "depth_000001.png").unlink()
    out_dir = tmp_path / "run"
    code, _, err = _main(["segment", str(scene_dir), "--out", str(out_dir)], capfd)
    assert code == 0
    warns = [ln for ln in err.splitlines() if ln.startswith("warning:")]
    assert warns == [
        "warning: frame 1 (image_000001.png): its depth file depth/depth_000001.png is missing, so it was taken"
        " as a post-interaction frame and is not segmented (list the frames in clutt3r_scene.json to make the"
        " roles explicit)"
    ]
    info = json.loads((out_dir / "run.json").read_text())
    assert [(w["code"], w["frame"]) for w in info["warnings"]] == [("frame-demoted", 1)]
    from clutt3r_core.runs import load_run, read_run_info

    assert read_run_info(out_dir).warnings == load_run(out_dir).warnings
    assert load_run(out_dir).trace.frames.tolist() == [0, 2]


def test_all_zero_depth_is_an_error_naming_the_views(scene_dir, tmp_path, capfd):
    for f in range(3):
        write_png(scene_dir / "depth" / f"depth_{f:06d}.png", np.zeros((120, 160), np.uint16))
    code, out, err = _main(["segment", str(scene_dir), "--out", str(tmp_path / "run")], capfd)
    assert code == 2 and out == ""
    assert err.count("\n") == 1
    assert err.startswith("clutt3r: error: no usable depth in any view (every depth pixel is a hole (0)")
    for f in range(3):
        assert f"frame {f} (image_{f:06d}.png)" in err
    assert not (tmp_path / "run").exists()


def test_no_depth_files_at_all_says_why_there_is_nothing_to_segment(scene_dir, tmp_path, capfd):
    (scene_dir / "clutt3r_scene.json").unlink()
    for f in range(3):
        (scene_dir / "depth" / f"depth_{f:06d}.png").unlink()
    code, _, err = _main(["segment", str(scene_dir), "--out", str(tmp_path / "run")], capfd)
    assert code == 2
    assert err.strip().endswith("no initial views to segment (frames [0, 1, 2] have no depth file, so they were"
                                " taken as post-interaction)"), err


def test_unwritable_output_path_is_named(scene_dir, tmp_path, capfd):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    code, _, err = _main(["segment", str(scene_dir), "--out", str(blocker / "run")], capfd)
    assert code == 2 and err.count("\n") == 1
    assert err.startswith(f"clutt3r: error: {blocker}") and "Not a directory" in err, err
