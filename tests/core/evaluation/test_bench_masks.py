"""``clutt3r bench --masks builtin``: the builtin generator's candidates replace the scene's on the
views a job uses, its time is the job's first stage, and the job key differs from the scene
setting's (so the result caches never mix); the scene setting's key keeps its old form."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation import runner
from clutt3r_core.evaluation.jobs import _method_config, _sha, code_version
from clutt3r_core.evaluation.runner import JobResult, SerialExecutor, Setting, job_key, plan_jobs, run_benchmark, synth_suite

pytestmark = pytest.mark.filterwarnings("ignore:Got image with third dimension")


def test_mask_source_is_part_of_the_key():
    spec = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3)[0]
    scene_key, builtin_key = job_key(spec, "ours", Setting(3)), job_key(spec, "ours", Setting(3, masks="builtin"))
    assert scene_key != builtin_key
    # results cached before the field existed (clean depth, the scene's masks) keep their key
    clean = spec.with_noise("grounded-sam-like", "none")
    old = _sha([clean.identity, "ours", _method_config("ours"), {"views": 3, "mask_noise": "grounded-sam-like"},
                code_version()])
    assert job_key(clean, "ours", Setting(3, depth_noise="none")) == old
    assert Setting(3, masks="builtin").label == "3v/grounded-sam-like/builtin" and Setting(3).label == "3v/grounded-sam-like"
    with pytest.raises(SceneError, match="mask source"):
        Setting(3, masks="sam")


def test_builtin_setting_runs_on_generated_candidates(tmp_path, monkeypatch):
    seen = []
    original = runner._run_method

    def spy(method, scene):
        seen.append(scene)
        return original(method, scene)

    monkeypatch.setattr(runner, "_run_method", spy)
    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=3)
    jobs = plan_jobs(scenes, ["ours"], [Setting(3), Setting(3, masks="builtin")], tmp_path)
    assert jobs[0].key != jobs[1].key
    res = run_benchmark(jobs, SerialExecutor(), progress=False)
    by = {r.masks: r for r in res}
    assert set(by) == {"scene", "builtin"}
    b = by["builtin"]
    assert b.stages[0][0] == "masks" and b.stages[0][1] > 0
    assert "masks" not in {s for s, _ in by["scene"].stages}
    assert 0.0 <= b.ap50 <= b.ap25 <= 100.0 and b.num_gt == 3
    assert JobResult.from_json(b.to_json()) == b
    # the method saw other candidates than the scene's own, on every view
    own, gen = seen
    for vo, vg in zip(own.initial_views, gen.initial_views):
        assert vo.frame == vg.frame
        assert vo.masks.masks.shape != vg.masks.masks.shape or not np.array_equal(vo.masks.masks, vg.masks.masks)
    # the report names the source of the main setting's candidates
    from clutt3r_core.evaluation.report import write_report

    md = write_report([b], tmp_path / "rep", main=Setting(3, masks="builtin")).read_text()
    assert "`builtin` mask candidates" in md
    assert json.loads((tmp_path / "rep" / "results.json").read_text())["main_setting"]["masks"] == "builtin"


def test_scene_setting_refuses_a_scene_without_candidates(tmp_path, monkeypatch):
    import dataclasses

    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=3)
    job = plan_jobs(scenes, ["ours"], [Setting(3)], tmp_path)[0]
    prep = runner._load_prepared(str(tmp_path), job.scene)
    bare = dataclasses.replace(prep.scene, views=tuple(dataclasses.replace(v, masks=None) for v in prep.scene.views))
    monkeypatch.setattr(runner, "_load_prepared", lambda cache, spec: runner._Prepared(bare, prep.mean_occlusion))
    with pytest.raises(SceneError, match="--masks builtin"):
        runner.run_job(job)
