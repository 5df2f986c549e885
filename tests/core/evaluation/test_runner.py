"""Runner end to end on tiny generated scenes with the serial executor; the second run hits the cache."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation import runner
from clutt3r_core.evaluation.report import write_report
from clutt3r_core.evaluation.runner import (
    JobResult,
    SerialExecutor,
    Setting,
    plan_jobs,
    run_benchmark,
    subset_views,
    synth_suite,
)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    # clean depth: at 160x120 the RealSense-like model's disparity noise is 4x coarser in depth and leaves
    # no object voxel; these tests are about the runner (the depth model: test_breakdown_suite.py)
    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=3, depth_noise="none")
    jobs = plan_jobs(scenes, ["ours", "naive", "maskclustering"], [Setting(3, depth_noise="none")], cache)
    jobs += plan_jobs(scenes, ["ours"], [Setting(2, depth_noise="none")], cache)
    first = run_benchmark(jobs, SerialExecutor(), progress=False)
    return cache, jobs, first


def test_results_are_valid(tiny_run):
    _, jobs, res = tiny_run
    assert [r.key for r in res] == [j.key for j in jobs]
    assert not any(r.cached for r in res)
    for r in res:
        assert 0.0 <= r.ap50 <= r.ap25 <= 100.0
        assert r.num_gt == 3 and (r.num_pred >= 1 or r.views < 3)
        assert r.seconds > 0 and r.wall_seconds >= r.seconds * 0.5 and r.maxrss_mb > 0
        assert len(r.match_tp) == len(r.match_thresholds) == 11
    ours = [r for r in res if r.method == "ours"]
    assert {r.views for r in ours} == {3, 2}
    assert {"pointcloud", "supervoxels", "grouping", "vote"} <= {s for s, _ in ours[0].stages}


def test_second_run_hits_cache(tiny_run, monkeypatch):
    cache, jobs, first = tiny_run

    def boom(*a, **k):
        raise AssertionError("a cached job was recomputed")

    monkeypatch.setattr(runner, "_run_method", boom)
    monkeypatch.setattr(runner, "prepare_scene", boom)
    again = run_benchmark(jobs, SerialExecutor(), progress=False)
    assert all(r.cached for r in again)
    assert [(r.ap25, r.ap50, r.ap) for r in again] == [(r.ap25, r.ap50, r.ap) for r in first]
    assert JobResult.from_json(again[0].to_json()) == again[0]


def test_report(tiny_run, tmp_path):
    _, _, res = tiny_run
    path = write_report(res, tmp_path / "out", command="clutt3r bench --suite tiny", main=Setting(3, depth_noise="none"))
    md = path.read_text()
    assert "Table I" in md and "Naive" in md and "MaskClustering (re-impl.)" in md
    assert "clutt3r bench --suite tiny" in md
    assert "Table IV" in md  # 2 vs 3 views of ours
    assert (tmp_path / "out" / "ap_vs_difficulty.png").stat().st_size > 1000
    assert (tmp_path / "out" / "time_per_stage.png").is_file()
    data = json.loads((tmp_path / "out" / "results.json").read_text())
    assert len(data["results"]) == len(res)


def test_key_changes_with_method_and_setting(tiny_run):
    cache, jobs, _ = tiny_run
    assert len({j.key for j in jobs}) == len(jobs)
    with pytest.raises(SceneError):
        plan_jobs(synth_suite(1, difficulties=("easy",)), ["nope"], [Setting()], cache)


def test_subset_views_spreads_over_frames(tiny_run):
    cache, jobs, _ = tiny_run
    prep = runner._load_prepared(str(cache), jobs[0].scene)
    s2 = subset_views(prep.scene, 2)
    assert [s2.views[i].frame for i in s2.initial] == [0, 2]
    assert subset_views(prep.scene, 8) is prep.scene
    assert np.isfinite(prep.mean_occlusion)


def test_noise_variant_changes_identity():
    s = synth_suite(1, difficulties=("hard",))[0]
    assert s.with_noise("grounded-sam-like") is s
    h = s.with_noise("harsh")
    assert h.identity != s.identity and h.synth["mask_noise"] == "harsh" and h.name == s.name
