"""What a benchmark is made of: scenes, settings, jobs, their results and the keys that cache them.

Shared by the runner (``evaluation/runner.py``), the report (``evaluation/report.py``) and the
``clutt3r bench`` command, so that none of them imports another for its types.
"""

from __future__ import annotations

import functools
import hashlib
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Iterable, Literal

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation.breakdown import ErrorBreakdown
from clutt3r_core.evaluation.methods import PRESET_OF  # noqa: F401  (importing it registers the ablation methods)

__all__ = [
    "METHODS",
    "DEFAULT_METHODS",
    "DIFFICULTIES",
    "MASK_NOISES",
    "DEPTH_NOISES",
    "MASK_SOURCES",
    "Method",
    "SceneSpec",
    "Setting",
    "Job",
    "JobResult",
    "job_key",
    "code_version",
    "synth_version",
]

Method = Literal["ours", "paper", "no-spatial", "no-substitution", "ours-noisy-depth", "naive", "maskclustering"]
METHODS: tuple[str, ...] = ("ours", "paper", "no-spatial", "no-substitution", "ours-noisy-depth", "naive", "maskclustering")
DEFAULT_METHODS: tuple[str, ...] = tuple(m for m in METHODS if m != "ours-noisy-depth")
"""What ``clutt3r bench`` runs unless told: every method but the noisy-depth preset. Ours already runs
the surface estimate where the views' depths disagree by >= 1 mm (``pointcloud.surface = "auto"``:
every RealSense-like scene), so the preset differs from ours on clean depth only, where its fusion
takes ~3.5x as long at 640x480 (docs/benchmark/strict-iou.md)."""
DIFFICULTIES: tuple[str, ...] = ("easy", "intermediate", "hard")
MASK_NOISES: tuple[str, ...] = ("clean", "grounded-sam-like", "harsh")
DEPTH_NOISES: tuple[str, ...] = ("realsense", "none")
"""Depth models of generated scenes (``synth.sensor``): the standard suite uses ``realsense``
(disparity noise, holes at depth edges and grazing angles, issue 13); ``none`` = clean
rendered depth, kept as a sweep."""
MaskSource = Literal["scene", "builtin"]
MASK_SOURCES: tuple[str, ...] = ("scene", "builtin")
"""Where a job's mask candidates come from: the scene's own (generated scenes: the mask-noise
model's; folders: their instance_masks/) or the builtin generator (``masks.ensure_candidates``),
which replaces them on every view used."""


def _sha(obj) -> str:
    return hashlib.sha256(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _source_hash(paths: Iterable[Path]) -> str:
    h = hashlib.sha256()
    for p in sorted(paths):
        h.update(str(p.name).encode())
        h.update(p.read_bytes())
    return h.hexdigest()[:12]


_PKG = Path(__file__).resolve().parents[1]


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """Hash of the package sources that decide a result (everything but the runner and report).

    Computed once per process, close to when the modules were imported: the tree may be
    edited while a long run goes on, and a worker keeps running the code it imported."""
    skip = {_PKG / "evaluation" / n for n in ("runner.py", "report.py", "jobs.py", "executors.py")} | {_PKG / "commands" / "bench.py"}
    return _source_hash(p for p in _PKG.rglob("*.py") if p not in skip)


def synth_version() -> str:
    """Hash of the generator's sources (a generated scene's identity)."""
    return _source_hash(list((_PKG / "synth").rglob("*.py")) + [_PKG / "scene.py"])


@dataclass(frozen=True)
class SceneSpec:
    """One benchmark scene.

    Attributes:
        name: scene name (unique in a benchmark).
        difficulty: easy / intermediate / hard, or "folder" for scenes without a preset.
        synth: the generator config as JSON-able data (``asdict(SynthConfig)``), or None.
        path: the scene folder for loaded scenes, or None.
        identity: content hash of what defines the scene (config + generator code, or file listing).
    """

    name: str
    difficulty: str
    synth: dict | None = None
    path: str | None = None
    identity: str = ""

    def with_noise(self, mask_noise: str, depth_noise: str | None = None) -> "SceneSpec":
        """The same generated scene with another mask-noise model and, if given, depth model
        (the objects and cameras are unchanged)."""
        if self.synth is None:
            return self
        depth_noise = depth_noise or self.synth.get("depth_noise", "none")
        if self.synth["mask_noise"] == mask_noise and self.synth.get("depth_noise", "none") == depth_noise:
            return self
        cfg = {**self.synth, "mask_noise": mask_noise, "depth_noise": depth_noise}
        return replace(self, synth=cfg, identity=_sha([cfg, synth_version()]))


@dataclass(frozen=True)
class Setting:
    """Views used (a subset of the scene's initial views), mask noise of generated scenes, the
    mask candidates' source (``MASK_SOURCES``; with ``builtin`` the noise model's candidates
    are replaced, so ``mask_noise`` only picks the cached scene variant) and the depth model of
    generated scenes (``DEPTH_NOISES``; scene folders keep their own depth)."""

    views: int = 8
    mask_noise: str = "grounded-sam-like"
    masks: str = "scene"
    depth_noise: str = "realsense"

    def __post_init__(self) -> None:
        if self.masks not in MASK_SOURCES:
            raise SceneError(f"unknown mask source '{self.masks}'; choose from {', '.join(MASK_SOURCES)}")
        if self.depth_noise not in DEPTH_NOISES:
            raise SceneError(f"unknown depth model '{self.depth_noise}'; choose from {', '.join(DEPTH_NOISES)}")

    @property
    def label(self) -> str:
        return (f"{self.views}v/{self.mask_noise}" + ("" if self.masks == "scene" else f"/{self.masks}")
                + ("" if self.depth_noise == "realsense" else f"/depth-{self.depth_noise}"))

    def key_data(self) -> dict:
        """What identifies the setting in a job key; ``masks="scene"`` and ``depth_noise="none"``
        (clean depth, all there was before the field existed) are left out so keys of results
        cached before the fields existed stay valid."""
        d = asdict(self)
        if d["masks"] == "scene":
            del d["masks"]
        if d["depth_noise"] == "none":
            del d["depth_noise"]
        return d


@dataclass(frozen=True)
class Job:
    """One (scene, method, setting). ``key`` is fixed when the job is planned (``plan_jobs``):
    the code may change while a long run is going on (other work in the same tree), and a
    result must come back under the key it was asked for."""

    scene: SceneSpec
    method: str
    setting: Setting
    cache_dir: str
    key: str = ""

    def __post_init__(self) -> None:
        if not self.key:
            object.__setattr__(self, "key", job_key(self.scene, self.method, self.setting))


def job_key(scene: SceneSpec, method: str, setting: Setting, version: str | None = None) -> str:
    """Content hash of a job: scene identity, method config, setting and code version."""
    return _sha([scene.identity, method, _method_config(method), setting.key_data(), version or code_version()])


@dataclass(frozen=True)
class JobResult:
    """One finished job: AP, time, memory, and the matches needed to pool AP over scenes.

    Times are seconds, memory MiB. ``stages`` are (stage, seconds) as the method reported
    them (``Segmentation.trace.timings`` for ours); ``wall_seconds`` is the whole call.
    ``peak_traced_mb`` is tracemalloc's peak (Python + numpy allocations of the job);
    ``maxrss_mb`` the worker's resident-set high-water mark after the job.
    """

    key: str
    scene: str
    difficulty: str
    mean_occlusion: float
    method: str
    views: int
    mask_noise: str
    ap25: float
    ap50: float
    ap: float
    per_threshold: tuple[tuple[float, float], ...]
    num_gt: int
    num_pred: int
    stages: tuple[tuple[str, float], ...]
    wall_seconds: float
    peak_traced_mb: float
    maxrss_mb: float
    match_scores: tuple[float, ...] = ()
    match_tp: tuple[tuple[bool, ...], ...] = ()
    match_thresholds: tuple[float, ...] = ()
    code_version: str = ""
    masks: str = "scene"
    depth_noise: str = "none"
    """The setting's depth model (``DEPTH_NOISES``; results cached before the field were on clean depth)."""
    breakdown: ErrorBreakdown | None = None
    """Where the scene's strict-IoU AP is lost (``evaluation.breakdown``); None in older results."""
    cached: bool = field(default=False, compare=False)

    @property
    def seconds(self) -> float:
        return float(sum(s for _, s in self.stages))

    def to_json(self) -> dict:
        d = asdict(self)
        d.pop("cached")
        d["breakdown"] = None if self.breakdown is None else self.breakdown.to_json()
        return d

    @staticmethod
    def from_json(d: dict, cached: bool = False) -> "JobResult":
        d = dict(d)
        d["per_threshold"] = tuple((float(a), float(b)) for a, b in d["per_threshold"])
        d["stages"] = tuple((str(a), float(b)) for a, b in d["stages"])
        d["match_scores"] = tuple(d.get("match_scores", ()))
        d["match_tp"] = tuple(tuple(bool(x) for x in row) for row in d.get("match_tp", ()))
        d["match_thresholds"] = tuple(d.get("match_thresholds", ()))
        d["breakdown"] = None if d.get("breakdown") is None else ErrorBreakdown.from_json(d["breakdown"])
        return JobResult(**d, cached=cached)

    def matches(self):
        from clutt3r_core.evaluation.metrics import InstanceMatches

        s = np.asarray(self.match_scores, np.float64)
        tp = np.asarray(self.match_tp, bool).reshape(len(self.match_thresholds), len(s))
        return InstanceMatches(np.asarray(self.match_thresholds), s, tp, self.num_gt, np.zeros((len(s), self.num_gt)))


def _method_config(method: str) -> dict:
    from clutt3r_core.evaluation.methods import method_config

    cfg = method_config(method)  # presets and the leave-one-out ablation (methods.ABLATION_METHODS)
    if cfg is not None:
        return asdict(cfg)
    if method == "naive":
        from clutt3r_core.baselines.naive import NaiveConfig

        return asdict(NaiveConfig())
    if method == "maskclustering":
        from clutt3r_core.baselines.maskclustering import MaskClusteringConfig

        return asdict(MaskClusteringConfig())
    raise SceneError(f"unknown method '{method}'; choose from {', '.join(METHODS)}")
