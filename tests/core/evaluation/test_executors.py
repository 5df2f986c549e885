"""The bench executors: a Dask cluster of two worker processes gives the serial executor's
results bit for bit, the content-hash cache holds across executors, and every way the cluster
can fail (bad address, dead worker, missing package) is one clear error."""

from __future__ import annotations

import dataclasses
import functools
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutt3r_core import registry as reg
from clutt3r_core.errors import Clutt3rError, MissingDependencyError, SceneError, SceneFileError
from clutt3r_core.evaluation import runner
from clutt3r_core.evaluation.executors import Executor, ExecutorError, SerialExecutor, create_executor
from clutt3r_core.evaluation.runner import SceneSpec, Setting, plan_jobs, run_benchmark, synth_suite

distributed = pytest.importorskip("distributed", reason="needs clutt3r[distributed] (pip install 'clutt3r[distributed]')")

# time and memory of a job are measurements of the run, not results; code_version is provenance
# (a worker imports the tree when it starts: in a working tree edited meanwhile it differs)
_RUN_FIELDS = ("stages", "wall_seconds", "peak_traced_mb", "maxrss_mb", "code_version")


def _results_only(r):
    return dataclasses.replace(r, stages=(), wall_seconds=0.0, peak_traced_mb=0.0, maxrss_mb=0.0, code_version="")


def _jobs(cache: Path):
    # clean depth, as test_runner's tiny run: 2 noisy 160x120 views can leave no instance
    scenes = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=3, depth_noise="none")
    return (plan_jobs(scenes, ["ours", "naive", "maskclustering"], [Setting(3, depth_noise="none")], cache)
            + plan_jobs(scenes, ["ours"], [Setting(2, depth_noise="none")], cache))


class _OwnDisk:
    """Wraps an executor as if its workers wrote to their own disks: every result file a worker
    wrote is removed before the runner sees the result (the runner must file it itself)."""

    def __init__(self, inner: Executor, results_dir: Path) -> None:
        self.inner, self.results_dir, self.calls = inner, results_dir, 0

    def map(self, fn, items):
        self.calls += 1
        for r in self.inner.map(fn, items):
            if fn is runner.run_job:
                (self.results_dir / f"{r.key}.json").unlink()
            yield r

    def close(self) -> None:
        pass


@pytest.fixture(scope="module")
def cluster():
    """A local cluster of 2 worker processes, 1 thread each. No retries: a task whose worker
    dies fails at once (the dead-worker test), instead of killing 3 more workers first."""
    import dask

    with dask.config.set({"distributed.scheduler.allowed-failures": 0}):
        ex = create_executor("dask", workers=2)
    try:
        yield ex
    finally:
        ex.close()


def test_bench_command_on_a_running_scheduler(cluster, tmp_path, monkeypatch):
    """``clutt3r bench --executor dask --address ...``: connects, checks the workers' code
    version, runs, files the results, writes the report; a second run is all cache."""
    from clutt3r_core.commands.bench import bench_command
    from clutt3r_core.evaluation import jobs as jobs_mod

    # first on the fresh cluster: its workers hash the tree at their first task, this process
    # now (in a working tree edited while the tests run, an older hash would differ, and the
    # check would rightly refuse)
    jobs_mod.code_version.cache_clear()
    tiny = synth_suite(1, difficulties=("easy",), width=160, height=120, views=3, n_objects=3, seed0=3)
    monkeypatch.setattr(runner, "synth_suite", lambda *a, **k: tiny)
    address = cluster.client.scheduler.address
    kw = dict(out=tmp_path / "out", methods=("naive",), view_sweep=False, noise_sweep=False, depth_sweep=False,
              executor="dask", address=address, cache=tmp_path / "cache", progress=False)
    bench_command(**kw)
    assert len(list((tmp_path / "cache" / "results").glob("*.json"))) == 1
    assert "with 2 worker(s)" in (tmp_path / "out" / "report.md").read_text()  # the cluster's threads
    monkeypatch.setattr(runner, "_run_method", lambda *a: pytest.fail("a cached job was recomputed"))
    bench_command(**kw)


def test_dask_results_equal_serial_and_the_cache_holds(cluster, tmp_path):
    assert cluster.workers == 2
    serial = run_benchmark(_jobs(tmp_path / "serial"), SerialExecutor(), progress=False)

    jobs = _jobs(tmp_path / "dask")
    assert [j.key for j in jobs] == [r.key for r in serial]  # the key names the work, not where it ran
    own = _OwnDisk(cluster, tmp_path / "dask" / "results")
    first = run_benchmark(jobs, own, progress=False)
    assert own.calls == 2  # scenes, then jobs: both on the cluster
    assert not any(r.cached for r in first)
    assert [_results_only(r) for r in first] == [_results_only(r) for r in serial]
    for a, b in zip(first, serial):  # bit for bit, not only dataclass equality of floats
        assert (a.ap, a.per_threshold, a.match_scores, a.match_tp) == (b.ap, b.per_threshold, b.match_scores, b.match_tp)
    assert {r.num_gt for r in first} == {3} and all(r.num_pred >= 1 for r in first)

    # the runner filed every result itself: a second run computes nothing and sends nothing
    again_ex = _OwnDisk(cluster, tmp_path / "dask" / "results")
    again = run_benchmark(jobs, again_ex, progress=False)
    assert again_ex.calls == 0 and all(r.cached for r in again)
    assert [_results_only(r) for r in again] == [_results_only(r) for r in first]


def test_a_job_error_reaches_the_caller_unchanged(cluster, tmp_path):
    broken = SceneSpec("broken", "folder", path=str(tmp_path / "no-such-scene"), identity="0" * 16)
    with pytest.raises(SceneFileError) as e:
        list(cluster.map(runner.prepare_scene, [(broken, str(tmp_path))]))
    assert e.value.path == tmp_path / "no-such-scene"  # the error itself, with its fields
    with pytest.raises(FileNotFoundError):  # an OSError of a job is the job's, not the connection's
        list(cluster.map(Path.read_text, [tmp_path / "missing.txt"]))
    make = functools.partial(Setting, 8, "clean")  # Setting(8, "clean", masks=item) checks masks
    with pytest.raises(SceneError, match="unknown mask source 'nope'"):
        list(cluster.map(make, ["scene", "nope"]))


@settings(max_examples=8, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.integers(-1000, 1000), max_size=12))
def test_every_item_comes_back_once(cluster, items):
    """Any order, but each item's result exactly once, duplicates included (Dask must not merge
    equal tasks: the runner's cache decides what is the same work)."""
    assert sorted(cluster.map(abs, items)) == sorted(map(abs, items))
    assert list(SerialExecutor().map(abs, items)) == [abs(x) for x in items]


def test_a_worker_with_other_code_refuses_to_compute():
    from clutt3r_core.evaluation.executors import _call_checked
    from clutt3r_core.evaluation.jobs import code_version

    assert _call_checked(abs, -2, code_version()) == 2 and _call_checked(abs, -2, None) == 2
    with pytest.raises(ExecutorError, match="runs clutt3r code version .*, the client 0123456789ab: install the same"):
        _call_checked(abs, -2, "0123456789ab")


def test_bad_address_is_one_clear_error():
    with pytest.raises(ExecutorError, match=r"cannot reach a Dask scheduler at 'tcp://127\.0\.0\.1:9'.*dask scheduler"):
        create_executor("dask", address="tcp://127.0.0.1:9", timeout=1)
    from clutt3r_core.commands.bench import bench_command

    with pytest.raises(Clutt3rError, match="--address is for --executor dask"):
        bench_command(executor="process", address="tcp://127.0.0.1:9", progress=False)


def test_bad_address_through_the_cli_is_one_line(capsys, tmp_path):
    import dask

    from clutt3r_core.cli import main

    with dask.config.set({"distributed.comm.timeouts.connect": "1s"}), pytest.raises(SystemExit) as e:
        main(["bench", "--suite", "tiny", "--executor", "dask", "--address", "tcp://127.0.0.1:9",
              "--out", str(tmp_path), "--cache", str(tmp_path / "c"), "--no-progress"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot reach a Dask scheduler" in err[0] and "Traceback" not in err[0]


def test_missing_package_names_the_extra(monkeypatch):
    real = reg.importlib.util.find_spec
    monkeypatch.setattr(reg.importlib.util, "find_spec", lambda m, *a: None if m == "distributed" else real(m, *a))
    with pytest.raises(MissingDependencyError, match=r"distributed.*pip install 'clutt3r\[distributed\]'"):
        create_executor("dask")
    assert {"serial", "process", "dask"} <= set(reg.backend_names("bench_executor"))
    assert reg.default_backend("bench_executor") == "process"


def test_a_dead_worker_is_one_clear_error(cluster):
    """Last in the module: it kills a worker (its nanny restarts it)."""
    with pytest.raises(ExecutorError, match=r"Dask workers died running _exit-0-\w+ \(on 1 worker\(s\)\)"):
        list(cluster.map(os._exit, [3]))
