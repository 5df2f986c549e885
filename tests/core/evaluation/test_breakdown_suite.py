"""The benchmark suite with the depth model (issue 13): RealSense-like depth by default, clean
depth as a sweep, and the per-scene error breakdown in every result and in the report."""

from __future__ import annotations

import json

import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation.breakdown import ERROR_KINDS
from clutt3r_core.evaluation.jobs import JobResult, Setting
from clutt3r_core.evaluation.report import write_report
from clutt3r_core.evaluation.runner import SerialExecutor, plan_jobs, run_benchmark, synth_suite


@pytest.fixture(scope="module")
def depth_run(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=5)
    jobs = plan_jobs(scenes, ["ours"], [Setting(3), Setting(3, depth_noise="none")], cache)
    return jobs, run_benchmark(jobs, SerialExecutor(), progress=False)


def test_realsense_depth_is_the_default():
    assert Setting().depth_noise == "realsense"
    assert synth_suite(1, difficulties=("easy",))[0].synth["depth_noise"] == "realsense"
    with pytest.raises(SceneError):
        Setting(depth_noise="kinect")


def test_depth_model_selects_the_scene_and_the_key(depth_run):
    jobs, res = depth_run
    noisy, clean = jobs
    assert noisy.scene.synth["depth_noise"] == "realsense" and clean.scene.synth["depth_noise"] == "none"
    assert noisy.scene.identity != clean.scene.identity and noisy.key != clean.key
    # clean depth keeps the key data it had before the field existed (cached results stay valid)
    assert "depth_noise" not in Setting(3, depth_noise="none").key_data()
    assert [r.depth_noise for r in res] == ["realsense", "none"]


def test_every_result_has_its_breakdown(depth_run):
    _, res = depth_run
    for r in res:
        b = r.breakdown
        assert b is not None and b.num_gt == r.num_gt and b.num_pred == r.num_pred
        assert b.ap == pytest.approx(r.ap)
        assert len(b.wrong_cells) == len(ERROR_KINDS)
        assert JobResult.from_json(json.loads(json.dumps(r.to_json()))) == r
    # noisy depth spills off the clean surface; clean depth far less so. Holes are not compared:
    # ours runs the surface estimate on noisy depth only (pointcloud.surface "auto"), and at 160x120
    # it keeps more of the surface (818 GT cells without a point) than the plain fusion of clean
    # depth does (1007: most voxels there hold fewer than 3 samples)
    off = ERROR_KINDS.index("off_gt")
    noisy, clean = res
    assert noisy.breakdown.wrong_cells[off] > clean.breakdown.wrong_cells[off]


def test_report_has_the_breakdown_and_the_depth_sweep(depth_run, tmp_path):
    _, res = depth_run
    path = write_report(res, tmp_path / "out", main=Setting(3))
    md = path.read_text()
    assert "## Where strict-IoU AP is lost (ours)" in md and "labelling ceiling" in md
    assert "## Depth-model sweep" in md and "none AP" in md
    table1 = md.split("## Table I")[1].split("##")[0]
    assert "`realsense` depth" in md and table1.count("Clutt3R (ours") == 1  # the clean-depth run is not in Table I
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(data["results"]) == 2 and data["main_setting"]["depth_noise"] == "realsense"
    assert data["results"][0]["breakdown"]["wrong_cells"]
