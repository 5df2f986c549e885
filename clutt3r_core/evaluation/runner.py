"""The benchmark runner behind ``clutt3r bench``.

A benchmark is a list of **jobs** ``(scene, method, setting)``:

* scenes: a named suite of generated scenes (``synth.generate_scene``, presets easy /
  intermediate / hard, N seeds each) or every scene folder with ground truth under a
  directory (``io.load_scene``);
* methods: ``ours`` (``PRESETS["default"]``), ``paper`` (``PRESETS["paper"]``, the paper's
  text without our additions), the ablations ``no-spatial`` and ``no-substitution``, and
  the baselines ``naive`` and ``maskclustering`` (a re-implementation from the paper's
  description, see ``baselines/maskclustering.py``);
* settings: number of views (a subset of the scene's initial views, evenly spread over
  the camera arc), the mask-noise model of generated scenes, and where the mask candidates
  come from (the scene's own, or the builtin generator: ``Setting.masks``).

Work is mapped over an ``Executor`` (``evaluation/executors.py``: ``ProcessExecutor``, local
processes, 2 workers by default; ``SerialExecutor`` for tests; ``DaskExecutor`` for a
cluster). Two caches make a run resumable:
``<cache>/scenes/<hash>.pkl`` holds prepared scenes (generation takes seconds each) and
``<cache>/results/<hash>.json`` one finished job, keyed by a content hash of the scene's
config, the method's config, the setting and the code version (a hash of the package
sources), so a changed algorithm never reuses a stale number. The report (Markdown,
JSON, PNG plots) is written by ``evaluation/report.py``; the types shared by both live in
``evaluation/jobs.py``; the command is ``clutt3r_core.commands.bench``.
"""

from __future__ import annotations

import json
import pickle
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.evaluation.executors import Executor, ProcessExecutor, SerialExecutor  # noqa: F401  (re-exported)
from clutt3r_core.evaluation.jobs import (  # noqa: F401  (re-exported: the runner's public names)
    DIFFICULTIES,
    MASK_NOISES,
    METHODS,
    Job,
    JobResult,
    Method,
    SceneSpec,
    Setting,
    _sha,
    code_version,
    job_key,
    synth_version,
)
from clutt3r_core.io.images import atomic_write_bytes

__all__ = [
    "METHODS",
    "DIFFICULTIES",
    "MASK_NOISES",
    "SceneSpec",
    "Setting",
    "Job",
    "JobResult",
    "Executor",
    "SerialExecutor",
    "ProcessExecutor",
    "synth_suite",
    "folder_suite",
    "plan_jobs",
    "run_benchmark",
    "run_job",
    "job_key",
    "code_version",
]


# ------------------------------------------------------------------ specs


def synth_suite(
    per_difficulty: int,
    difficulties: Sequence[str] = DIFFICULTIES,
    width: int = 640,
    height: int = 480,
    views: int = 8,
    mask_noise: str = "grounded-sam-like",
    seed0: int = 0,
    n_objects: int | None = None,
    depth_noise: str = "realsense",
) -> list[SceneSpec]:
    """Generated scenes: seeds seed0 .. seed0 + per_difficulty - 1 of each difficulty preset.

    ``depth_noise``: the depth model (``jobs.DEPTH_NOISES``); RealSense-like by default, as a
    robot's camera measures (issue 13: clean rendered depth hid most of the strict-IoU loss)."""
    from clutt3r_core.synth.generator import SynthConfig

    out = []
    sv = synth_version()
    for d in difficulties:
        for s in range(seed0, seed0 + per_difficulty):
            cfg = asdict(SynthConfig(seed=s, preset=d, views=views, width=width, height=height,
                                     mask_noise=mask_noise, n_objects=n_objects, depth_noise=depth_noise))
            out.append(SceneSpec(f"synth_{d}_{s:04d}", d, synth=cfg, identity=_sha([cfg, sv])))
    return out


def folder_suite(root: str | Path) -> list[SceneSpec]:
    """Every scene folder with ground truth under ``root`` (or ``root`` itself)."""
    root = Path(root)
    if not root.is_dir():
        raise SceneFileError(root, "benchmark scene folder not found")
    marks = ("transforms.json", "scene_camera.json")
    cands = [root] if any((root / m).is_file() for m in marks) else sorted(
        p for p in root.iterdir() if p.is_dir() and any((p / m).is_file() or (p / "data" / m).is_file() for m in marks))
    if not cands:
        raise SceneFileError(root, "no scene folders (transforms.json or scene_camera.json) found")
    out = []
    for p in cands:
        listing = sorted((str(f.relative_to(p)), f.stat().st_size, int(f.stat().st_mtime)) for f in p.rglob("*") if f.is_file())
        diff = "folder"
        info = p / "gt" / "synth_info.json"
        if info.is_file():
            try:
                diff = json.loads(info.read_text())["config"]["preset"]
            except (KeyError, ValueError):
                pass
        out.append(SceneSpec(p.name, diff, path=str(p.resolve()), identity=_sha([str(p.resolve()), listing])))
    return out


# ------------------------------------------------------------------ scenes


@dataclass(frozen=True, eq=False)
class _Prepared:
    scene: object  # clutt3r_core.scene.Scene
    mean_occlusion: float


def _scene_file(cache_dir: str | Path, spec: SceneSpec) -> Path:
    return Path(cache_dir) / "scenes" / f"{spec.identity}.pkl"


def prepare_scene(args: tuple[SceneSpec, str]) -> str:
    """Generate or load a scene into the scene cache (no-op when cached). Returns its name."""
    spec, cache_dir = args
    path = _scene_file(cache_dir, spec)
    if path.is_file():
        return spec.name
    if spec.synth is not None:
        from clutt3r_core.synth.generator import SynthConfig, generate

        cfg = dict(spec.synth)
        for k in ("distance", "elevation_deg", "objects"):
            if cfg.get(k) is not None:
                cfg[k] = tuple(cfg[k])
        res = generate(SynthConfig(**cfg), progress=False)
        prep = _Prepared(res.scene, float(res.info.mean_occlusion))
    else:
        from clutt3r_core.io import load_scene

        scene = load_scene(spec.path)
        if scene.ground_truth is None or len(scene.ground_truth.points) == 0:
            raise SceneFileError(spec.path, "scene has no ground-truth points (gt/points.npz): cannot evaluate")
        occ = float("nan")
        try:
            from clutt3r_core.synth.generator import load_synth_info

            occ = float(load_synth_info(spec.path).mean_occlusion)
        except (SceneError, ImportError, OSError):
            pass
        prep = _Prepared(scene, occ)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(path, pickle.dumps(prep, protocol=5))
    return spec.name


def _load_prepared(cache_dir: str, spec: SceneSpec) -> _Prepared:
    path = _scene_file(cache_dir, spec)
    if not path.is_file():
        prepare_scene((spec, cache_dir))
    with open(path, "rb") as f:
        return pickle.load(f)


def subset_views(scene, n: int):
    """The scene with ``n`` of its initial views, evenly spread over them in frame order."""
    from clutt3r_core.scene import Scene

    init = sorted(scene.initial, key=lambda i: scene.views[i].frame)
    if n >= len(init):
        return scene
    if n < 1:
        raise SceneError(f"cannot keep {n} views")
    pick = np.unique(np.round(np.linspace(0, len(init) - 1, n)).astype(int))
    return Scene(scene.views, tuple(init[i] for i in pick), scene.post, scene.ground_truth, scene.name, scene.root)


# ------------------------------------------------------------------ jobs


def _run_method(method: str, scene):
    from clutt3r_core.registry import create_backend

    return create_backend("bench_method", method).predict(scene)


def _result_file(job: Job) -> Path:
    return Path(job.cache_dir) / "results" / f"{job.key}.json"


def run_job(job: Job) -> JobResult:
    """Run one job (or read it from the result cache) and cache the result."""
    from clutt3r_core.evaluation.metrics import MemoryProbe, evaluate_instances, stage_times

    rf = _result_file(job)
    if rf.is_file():
        try:
            return JobResult.from_json(json.loads(rf.read_text()), cached=True)
        except (ValueError, KeyError, TypeError):
            pass  # a stale or damaged entry is recomputed
    prep = _load_prepared(job.cache_dir, job.scene)
    scene = subset_views(prep.scene, job.setting.views)
    t0 = time.perf_counter()
    with MemoryProbe() as mem:
        from clutt3r_core.masks import ensure_candidates, scene_has_masks

        mask_stage: tuple[tuple[str, float], ...] = ()
        if job.setting.masks != "scene":
            # replaced on the views used only; the generator's time is the job's first stage
            scene, prov = ensure_candidates(scene, job.setting.masks)
            mask_stage = (("masks", prov.seconds),)
        elif not scene_has_masks(scene):
            # ours would fill them in (segment's masks="auto") and the baselines refuse: a result
            # labelled "scene" must be on the scene's own candidates
            raise SceneError(f"{job.scene.name}: views without mask candidates; run with --masks builtin")
        pred = _run_method(job.method, scene)
    wall = time.perf_counter() - t0
    ap, m = evaluate_instances(pred.points, pred.instance, pred.scores, scene.ground_truth)
    from clutt3r_core.evaluation.breakdown import error_breakdown

    breakdown = error_breakdown(pred.points, pred.instance, pred.scores, scene.ground_truth)
    res = JobResult(
        key=job.key, scene=job.scene.name, difficulty=job.scene.difficulty, mean_occlusion=prep.mean_occlusion,
        method=job.method, views=len(scene.initial), mask_noise=job.setting.mask_noise,
        ap25=ap.ap25, ap50=ap.ap50, ap=ap.ap, per_threshold=ap.per_threshold, num_gt=ap.num_gt,
        num_pred=ap.num_pred, stages=mask_stage + stage_times(pred.timings).stages, wall_seconds=wall,
        peak_traced_mb=mem.peak_traced_mb, maxrss_mb=mem.maxrss_mb,
        match_scores=tuple(float(x) for x in m.scores), match_tp=tuple(tuple(bool(x) for x in r) for r in m.tp),
        match_thresholds=tuple(float(t) for t in m.thresholds), code_version=code_version(),
        masks=job.setting.masks,
        depth_noise=job.setting.depth_noise if job.scene.synth is not None else "scene",
        breakdown=breakdown,
    )
    rf.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(rf, json.dumps(res.to_json()).encode())
    return res


def _store_result(res: JobResult, job: Job) -> None:
    """File a result received from an executor in this process's cache: a worker on another
    machine wrote it into its own disk (or nowhere reachable from here)."""
    rf = _result_file(job)
    if not rf.is_file():
        rf.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_bytes(rf, json.dumps(res.to_json()).encode())


def plan_jobs(
    scenes: Sequence[SceneSpec],
    methods: Sequence[str],
    settings: Sequence[Setting],
    cache_dir: str | Path,
) -> list[Job]:
    """Every (scene, method, setting); a setting's mask noise selects the scene variant."""
    jobs = []
    version = code_version()
    for st in settings:
        for sc in scenes:
            spec = sc.with_noise(st.mask_noise, st.depth_noise)
            for m in methods:
                jobs.append(Job(spec, m, st, str(cache_dir), job_key(spec, m, st, version)))  # unknown method raises
    return jobs


def run_benchmark(
    jobs: Sequence[Job],
    executor: Executor | None = None,
    progress: bool = True,
) -> list[JobResult]:
    """Prepare the scenes the jobs need, then run the jobs not yet cached. Results in job order."""
    from tqdm.auto import tqdm

    executor = executor or ProcessExecutor()
    specs = {j.scene.identity: (j.scene, j.cache_dir) for j in jobs}
    todo_scenes = [s for s in specs.values() if not _scene_file(s[1], s[0]).is_file()]
    # scenes that only cached jobs need are not generated
    pending = [j for j in jobs if not _result_file(j).is_file()]
    need = {j.scene.identity for j in pending}
    todo_scenes = [s for s in todo_scenes if s[0].identity in need]
    if todo_scenes:
        bar = tqdm(total=len(todo_scenes), desc="scenes", unit="scene", disable=not progress)
        for name in executor.map(prepare_scene, todo_scenes):
            bar.set_postfix_str(name)
            bar.update(1)
        bar.close()
    by_key: dict[str, JobResult] = {}
    cached = [j for j in jobs if j not in pending]
    for j in cached:
        by_key[j.key] = run_job(j)  # reads the cache
    job_of = {j.key: j for j in pending}
    if pending:
        # heavy jobs first: better load balance over the workers
        order = {"hard": 0, "intermediate": 1, "easy": 2}
        pending.sort(key=lambda j: (order.get(j.scene.difficulty, 3), j.scene.name, j.method))
        bar = tqdm(total=len(pending), desc="jobs", unit="job", disable=not progress)
        for r in executor.map(run_job, pending):
            by_key[r.key] = r
            _store_result(r, job_of[r.key])
            bar.set_postfix_str(f"{r.scene} {r.method} AP50 {r.ap50:.0f}")
            bar.update(1)
        bar.close()
    return [by_key[j.key] for j in jobs]
