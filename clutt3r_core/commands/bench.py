"""``clutt3r bench``: benchmark our method, its ablations and the baselines (evaluation/runner.py)."""

from __future__ import annotations

import time
from pathlib import Path
from typing import Literal

from clutt3r_core.evaluation.jobs import DEFAULT_METHODS, DIFFICULTIES, Method, Setting

__all__ = ["bench_command"]


def bench_command(
    out: Path = Path("out/bench"),
    suite: Literal["standard", "quick", "tiny"] = "standard",
    per_difficulty: int = 0,
    scenes_dir: Path | None = None,
    methods: tuple[Method, ...] = DEFAULT_METHODS,  # type: ignore[assignment]
    view_sweep: bool = True,
    noise_sweep: bool = True,
    ablation: bool = False,
    sweep_per_difficulty: int = 2,
    masks: Literal["scene", "builtin"] = "scene",
    depth_noise: Literal["realsense", "none"] = "realsense",
    depth_sweep: bool = True,
    width: int = 0,
    height: int = 0,
    seed0: int = 0,
    workers: int = 2,
    executor: str = "process",
    address: str | None = None,
    cache: Path = Path(".bench-cache"),
    markdown: Path | None = None,
    notes: Path | None = None,
    progress: bool = True,
) -> None:
    """Benchmark 3D instance segmentation: our method, its ablations and the baselines.

    Writes OUT/report.md, OUT/results.json and OUT/*.png (Tables I, III, IV of the paper, a
    mask-noise sweep, per-stage times, memory). Finished jobs are cached under CACHE, so an
    interrupted run resumes where it stopped.

    Args:
        out: report folder.
        suite: generated scenes: standard = 6 per difficulty at 640x480; quick = 2 per
            difficulty at 640x480; tiny = 1 per difficulty at 160x120 (smoke test).
        per_difficulty: override the suite's number of scenes per difficulty (0 = suite default).
        scenes_dir: evaluate these scene folders (with gt/points.npz) instead of generated scenes.
        methods: methods to run on the main setting (8 views, grounded-sam-like masks); add
            ours-noisy-depth for the surface estimate forced on (ours runs it when the depth is noisy;
            the preset differs on clean depth only, with a slower fusion, so not in the default list).
        view_sweep: also run ours and the baselines with 4 and 6 of the 8 views (Table IV).
        noise_sweep: also run ours and the baselines on clean and harsh mask candidates.
        ablation: also run the leave-one-out ablation of our additions over the paper on every
            scene of the main setting: ours with each one off, the paper preset with each one on
            (``evaluation.methods.ABLATION_METHODS``; docs/paper_choices.md).
        sweep_per_difficulty: scenes per difficulty used by the sweeps (the first ones).
        masks: mask candidates of every job: scene = the scene's own (generated scenes: the
            mask-noise model's); builtin = the builtin RGB-D generator's, made per job (no noise
            sweep then: the generator replaces the noise model's candidates). Part of the job key.
        depth_noise: depth model of generated scenes: realsense = RealSense-like disparity noise
            and holes (``synth/sensor.py``, the default), none = clean rendered depth.
        depth_sweep: also run ours and the baselines with the other depth model on the sweep subset.
        width: image width of generated scenes (0 = suite default).
        height: image height of generated scenes (0 = suite default).
        seed0: first seed of the generated scenes.
        workers: worker processes of the process executor or of a local Dask cluster (1 with
            the process executor = run serially in this process).
        executor: where jobs run: process (local worker processes), serial (this process),
            dask (a Dask distributed cluster; needs clutt3r[distributed]), or one a plugin
            registered (``clutt3r doctor`` lists them). Results are the same on each.
        address: the Dask scheduler (tcp://host:8786) to send jobs to; without it, --executor
            dask starts a local cluster of WORKERS processes. Workers need the same clutt3r
            checkout and any --scenes-dir at the same path; results come back to CACHE here
            (docs/benchmark.md, "Running on a Dask cluster").
        cache: cache folder for scenes and finished jobs.
        markdown: where to write the Markdown report (default OUT/report.md); plot links are
            relative to it (e.g. --out docs/benchmark --markdown docs/benchmark.md).
        notes: a Markdown file whose text is inserted after the tables (hand-written analysis).
        progress: show progress bars.
    """
    import contextlib
    import shlex
    import sys

    from clutt3r_core.errors import Clutt3rError
    from clutt3r_core.evaluation.executors import create_executor
    from clutt3r_core.evaluation.report import write_report
    from clutt3r_core.evaluation.runner import (
        folder_suite,
        plan_jobs,
        run_benchmark,
        synth_suite,
    )

    defaults = {"standard": (6, 640, 480), "quick": (2, 640, 480), "tiny": (1, 160, 120)}[suite]
    n = per_difficulty or defaults[0]
    w, h = width or defaults[1], height or defaults[2]
    if address is not None and executor != "dask":
        raise Clutt3rError(f"--address is for --executor dask, not '{executor}'")
    # absolute: a worker's working directory is not ours (and on a cluster, a shared mount)
    cache = cache.resolve()
    t0 = time.perf_counter()
    main = Setting(8, "grounded-sam-like", masks, depth_noise)
    if masks != "scene":
        noise_sweep = False  # every noise variant would get the same generated candidates
    if scenes_dir is not None:
        scenes = folder_suite(scenes_dir)
        sweep_scenes = scenes[: max(1, sweep_per_difficulty)]
        noise_sweep = False  # a folder's masks are what they are
        depth_sweep = False  # and so is its depth
    else:
        scenes = synth_suite(n, width=w, height=h, seed0=seed0)
        sweep_scenes = [s for d in DIFFICULTIES for s in [x for x in scenes if x.difficulty == d][:sweep_per_difficulty]]
    jobs = plan_jobs(scenes, methods, [main], cache)
    sweep_methods = [m for m in ("ours", "naive", "maskclustering") if m in methods]
    if view_sweep:
        jobs += plan_jobs(sweep_scenes, sweep_methods, [Setting(4, main.mask_noise, masks, depth_noise),
                                                        Setting(6, main.mask_noise, masks, depth_noise)], cache)
    if noise_sweep:
        jobs += plan_jobs(sweep_scenes, sweep_methods, [Setting(8, "clean", depth_noise=depth_noise),
                                                        Setting(8, "harsh", depth_noise=depth_noise)], cache)
    if depth_sweep:
        other = "none" if depth_noise == "realsense" else "realsense"
        jobs += plan_jobs(sweep_scenes, sweep_methods, [Setting(8, main.mask_noise, masks, other)], cache)
    if ablation:
        from clutt3r_core.evaluation.methods import ABLATION_METHODS

        jobs += plan_jobs(scenes, [m for m in ("ours", "paper") if m not in methods] + list(ABLATION_METHODS), [main], cache)
    if executor == "process" and workers <= 1:
        executor = "serial"
    options = {"process": {"workers": workers}, "dask": {"address": address, "workers": workers}}.get(executor, {})
    # connects (or starts the local cluster) before any work: a bad address fails here, in one line
    with contextlib.closing(create_executor(executor, **options)) as ex:
        results = run_benchmark(jobs, ex, progress=progress)
        workers = int(getattr(ex, "workers", 1))  # a cluster's: its worker threads
    elapsed = time.perf_counter() - t0
    command = "clutt3r bench " + " ".join(shlex.quote(a) for a in sys.argv[2:]) if len(sys.argv) > 1 and sys.argv[1] == "bench" else ""
    path = write_report(results, out, command=command, elapsed=elapsed, workers=workers, main=main, markdown=markdown,
                        notes=notes.read_text() if notes is not None and notes.is_file() else "")
    print(f"{len(results)} jobs ({sum(r.cached for r in results)} cached) in {elapsed:.0f} s -> {path}")
