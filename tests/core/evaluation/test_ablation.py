"""The leave-one-out ablation of our additions: method names, configs, job keys and the report table."""

from __future__ import annotations

from dataclasses import fields, replace

import pytest

from clutt3r_core.config import ADDITIONS, PRESETS, ours_without, paper_with
from clutt3r_core.evaluation.methods import ABLATION_METHODS, method_config
from clutt3r_core.evaluation.report import ablation_tables, write_report
from clutt3r_core.evaluation.runner import JobResult, SerialExecutor, Setting, plan_jobs, run_benchmark, synth_suite
from clutt3r_core.registry import backend_names


def test_every_addition_has_both_ablation_methods_registered():
    names = set(backend_names("bench_method"))
    for a in ADDITIONS:
        assert method_config(f"ours-no-{a.key}") == ours_without(a.key)
        assert method_config(f"paper-with-{a.key}") == paper_with(a.key)
        assert {f"ours-no-{a.key}", f"paper-with-{a.key}"} <= names
    assert len(ABLATION_METHODS) == 2 * len(ADDITIONS)
    assert method_config("ours") == PRESETS["default"] and method_config("paper") == PRESETS["paper"]
    assert method_config("naive") is None


def test_ablation_job_keys_are_distinct(tmp_path):
    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3)
    jobs = plan_jobs(scenes, ["ours", "paper", *ABLATION_METHODS], [Setting(3)], tmp_path)
    assert len({j.key for j in jobs}) == len(jobs)


def _fake(method: str, ap50: float, scene: str = "s0") -> JobResult:
    r = JobResult(key=f"{method}-{scene}", scene=scene, difficulty="easy", mean_occlusion=0.1, method=method,
                  views=8, mask_noise="grounded-sam-like", ap25=ap50 + 5, ap50=ap50, ap=ap50 / 2,
                  per_threshold=(), num_gt=3, num_pred=3, stages=(("grouping", 0.1),), wall_seconds=0.2,
                  peak_traced_mb=1.0, maxrss_mb=10.0)
    # in the main setting, whatever else a result records about it (e.g. the depth model)
    extra = {f.name: getattr(Setting(), f.name) for f in fields(Setting) if f.name in {g.name for g in fields(JobResult)}
             and f.name not in ("views", "mask_noise", "masks")}
    return replace(r, **extra)


def test_the_table_shows_each_addition_against_ours_and_the_paper():
    res = [_fake("ours", 90.0), _fake("paper", 60.0), _fake("ours-no-support", 80.0), _fake("paper-with-support", 70.0)]
    md = ablation_tables(res, {"ours": {"sample_seq1": 0.95}, "ours-no-support": {"sample_seq1": 0.9}})
    row = next(line for line in md.splitlines() if line.startswith("| `support` off"))
    assert "| 80.0 | 40.0 | -10.0 | -5.0 | 0.900 |" in row
    row = next(line for line in md.splitlines() if line.startswith("| `support` on"))
    assert "| 70.0 | 35.0 | 10.0 | 5.0 |" in row
    # additions not run are shown as such, not as zeros
    assert "| `one-mask-per-view` off | a group holds at most one mask per view | – |" in md
    assert ablation_tables([_fake("ours", 90.0)]) == ""


@pytest.fixture(scope="module")
def tiny_ablation(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=3)
    methods = ["ours", "ours-no-one-mask-per-view", "paper-with-background-masks"]
    return run_benchmark(plan_jobs(scenes, methods, [Setting(3)], cache), SerialExecutor(), progress=False)


def test_ablation_methods_run_through_the_runner(tiny_ablation):
    assert [r.method for r in tiny_ablation] == ["ours", "ours-no-one-mask-per-view", "paper-with-background-masks"]
    for r in tiny_ablation:
        assert 0.0 <= r.ap50 <= r.ap25 <= 100.0 and r.num_gt == 3


def test_the_report_keeps_ablation_methods_out_of_table_one(tiny_ablation, tmp_path):
    md = write_report(tiny_ablation, tmp_path / "out", main=Setting(3)).read_text()
    table1 = md.split("## Table I:")[1].split("##")[0]
    assert "one-mask-per-view" not in table1 and "background-masks" not in table1
    section = md.split("## Leave-one-out ablation")[1]
    assert "`one-mask-per-view` off" in section and "`background-masks` on" in section
