"""`clutt3r grasp RUN --instance K --json`: the last stdout line is the JSON object; files are written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.cli import main
from clutt3r_core.grasping import GraspSet


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    from clutt3r_core.runs import save_run
    from clutt3r_core.synth import write_synth_scene
    from tests.core._tiny_run import tiny_scene, tiny_segmentation

    root = tmp_path_factory.mktemp("grasp")
    write_synth_scene(tiny_scene(), root / "scene")
    return save_run(tiny_segmentation(), root / "run", scene_root=root / "scene")


def _last_json(capsys) -> dict:
    out = capsys.readouterr().out.strip().splitlines()
    return json.loads(out[-1])


def test_grasp_json_and_files(run_dir, capsys, tmp_path):
    Tb = np.eye(4)
    Tb[:3, 3] = [0.4, 0.0, 0.0]
    (tmp_path / "base.json").write_text(json.dumps(Tb.tolist()))
    main(["grasp", str(run_dir), "--instance", "0", "--json", "--top", "3", "--base-frame", str(tmp_path / "base.json")])
    obj = _last_json(capsys)
    assert obj["target"] == 0 and obj["query"] is None and len(obj["grasps"]) <= 3
    assert json.loads((run_dir / "grasps.json").read_text())["grasps"] == obj["grasps"]
    gs = GraspSet.load(run_dir / "grasps.npz")
    assert len(gs) == len(obj["grasps"])
    for g, T in zip(obj["grasps"], gs.poses):
        np.testing.assert_allclose(g["T_world_gripper"], T, atol=1e-9)
        np.testing.assert_allclose(g["T_base_gripper"], Tb @ T, atol=1e-9)
    scores = [g["score"] for g in obj["grasps"]]
    assert scores == sorted(scores, reverse=True)
    assert "message" not in obj or "unseen" not in obj["message"]  # the run recorded its scene: views used


def test_no_grasp_is_an_empty_list_not_a_crash(run_dir, capsys):
    main(["grasp", str(run_dir), "--instance", "0", "--json", "--config.pair-angle-deg", "0.01",
          "--config.relaxed-angle-deg", "0.01"])
    obj = _last_json(capsys)
    assert obj["grasps"] == [] and "no grasp" in obj["message"]
    assert json.loads((run_dir / "grasps.json").read_text())["grasps"] == []


@pytest.mark.parametrize("args, msg", [
    ([], "exactly one"),
    (["mug", "--instance", "0"], "exactly one"),
    (["--instance", "99"], "does not exist"),
])
def test_bad_arguments_are_one_clear_line(run_dir, args, msg):
    with pytest.raises(SystemExit, match=msg):
        main(["grasp", str(run_dir), *args])


def test_run_without_its_scene_falls_back_to_cloud_only_and_says_so(tmp_path, capsys):
    from clutt3r_core.grasping.request import run_views
    from clutt3r_core.runs import save_run
    from tests.core._tiny_run import tiny_segmentation

    run = save_run(tiny_segmentation(), tmp_path / "run")  # no scene recorded
    views, warn = run_views(run)
    assert views == () and "cloud only" in warn
    main(["grasp", str(run), "--instance", "0", "--json"])
    captured = capsys.readouterr()
    assert "cloud only" in captured.err
    obj = json.loads(captured.out.strip().splitlines()[-1])
    assert obj["target"] == 0 and isinstance(obj["grasps"], list)
