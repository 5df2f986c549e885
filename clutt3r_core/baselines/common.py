"""What every baseline shares with our method, so that only the grouping differs.

``mask_evidence`` runs the same front end as ``pipeline.segment``: the same fused cloud
(``fuse_views`` with ``SegmentConfig().pointcloud``), the same super-voxels (only their
support flags are used: table, tray floor and walls), the same mask candidates with the
same tiny-mask filter as the instance trees (``trees.min_mask_area``), and the same
background rule (``segmentation.evidence.background_masks``: mostly on support, or no 3D
evidence at all; never grouped). Each mask becomes the set of voxels its pixels fed (``mask_voxel_hits``).
``assign_by_majority`` turns groups of masks into per-point instances with our vote's
filters (support voxels stay unlabelled, specks under ``min_instance_points`` raw points
are dropped), so the instance output is the same form as ``Segmentation``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np
import scipy.sparse as sp

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Scene
from clutt3r_core.segmentation.trace import StageClock, StageTiming
from clutt3r_core.segmentation.vote import renumber_by_score

__all__ = ["Prediction", "MaskEvidence", "mask_evidence", "assign_by_majority", "run_baseline", "StageClock"]


@dataclass(frozen=True, eq=False)
class Prediction:
    """3D instances of a scene, in the form every method is evaluated in.

    Attributes:
        points: (N, 3) float32 world metres (the fused voxel centres).
        instance: (N,) int32 instance id per point, -1 = none; ids 0..K-1.
        scores: (K,) float32 confidence of each instance.
        timings: seconds per stage, in order.
        method: the method's name.
    """

    points: np.ndarray
    instance: np.ndarray
    scores: np.ndarray
    timings: tuple[StageTiming, ...] = ()
    method: str = ""

    def __post_init__(self) -> None:
        n = np.asarray(self.points).shape[0]
        inst = np.asarray(self.instance, np.int32).reshape(-1)
        sc = np.asarray(self.scores, np.float32).reshape(-1)
        if np.asarray(self.points).shape != (n, 3) or inst.shape != (n,):
            raise SceneError(f"Prediction: points (N, 3) and instance (N,) must agree, got {np.shape(self.points)}, {inst.shape}")
        if n and (inst.min() < -1 or inst.max() >= len(sc)):
            raise SceneError(f"Prediction: instance ids must lie in -1..{len(sc) - 1}")
        object.__setattr__(self, "instance", inst)
        object.__setattr__(self, "scores", sc)

    @property
    def num_instances(self) -> int:
        return len(self.scores)




@dataclass(frozen=True, eq=False)
class MaskEvidence:
    """Every usable mask of the initial views as a set of voxels of the shared fused cloud.

    Attributes:
        points: (N, 3) float32 voxel centres, metres.
        counts: (N,) int32 raw points per voxel.
        visibility: (V, N) bool, voxel fed by a pixel of view v.
        support: (N,) bool, voxel lies on a support super-voxel.
        voxels: (M, N) CSR float32 0/1, mask m fed voxel n.
        view: (M,) int32 view index (0..V-1, views sorted by frame) of each mask.
        mask_id: (M,) int32 id of each mask within its view.
        frames: (V,) frames of the views.
        background: (M,) bool, mask lies mostly on support (dropped by the baselines).
    """

    points: np.ndarray
    counts: np.ndarray
    visibility: np.ndarray
    support: np.ndarray
    voxels: sp.csr_matrix
    view: np.ndarray
    mask_id: np.ndarray
    frames: tuple[int, ...]
    background: np.ndarray
    timings: tuple[StageTiming, ...] = field(default=())

    @property
    def num_masks(self) -> int:
        return int(self.voxels.shape[0])

    @property
    def num_views(self) -> int:
        return len(self.frames)


def mask_evidence(scene: Scene, config=None, clock: StageClock | None = None) -> MaskEvidence:
    """The shared front end (module docstring). ``config``: a ``SegmentConfig`` (default: ours)."""
    from clutt3r_core.config import SegmentConfig
    from clutt3r_core.occupancy import mask_voxel_hits
    from clutt3r_core.pointcloud import fuse_views
    from clutt3r_core.segmentation.evidence import background_masks, check_views
    from clutt3r_core.segmentation.trees import min_mask_area
    from clutt3r_core.supervoxels import build_supervoxels

    cfg = config if config is not None else SegmentConfig()
    clock = clock if clock is not None else StageClock()
    check_views(scene)
    views = sorted(scene.initial_views, key=lambda v: v.frame)
    with clock("pointcloud"):
        cloud = fuse_views(views, cfg.pointcloud)
    with clock("supervoxels"):
        sv = build_supervoxels(cloud, cfg.supervoxels)
        support = sv.support[sv.labels] if cloud.num else np.zeros(0, bool)
    with clock("mask_voxels"):
        rows, view, mids, bg = [], [], [], []
        for vi, v in enumerate(views):
            m = v.masks
            h, w = m.shape if len(m) else (v.camera.height, v.camera.width)
            min_area = min_mask_area(cfg.trees, h, w)
            order = np.argsort(m.ids, kind="stable")
            keep = order[m.areas()[order] >= min_area] if len(m) else order
            if len(keep) == 0:
                continue
            # the kept candidates, sharing the view's code image (m.masks would build and keep
            # the whole (M, H, W) stack on the view; issue 13)
            hits = mask_voxel_hits(cloud, vi, m.select(keep))
            bg.append(background_masks(hits, support, cfg.background_fraction))
            hits = hits.tocsr()
            hits.data[:] = 1.0  # a mask is the set of voxels it fed
            rows.append(hits)
            view.append(np.full(len(keep), vi, np.int32))
            mids.append(m.ids[keep].astype(np.int32))
        voxels = sp.vstack(rows).tocsr().astype(np.float32) if rows else sp.csr_matrix((0, cloud.num), dtype=np.float32)
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    return MaskEvidence(
        points=cloud.points, counts=cloud.counts, visibility=cloud.visibility, support=support,
        voxels=voxels, view=cat(view, np.int32), mask_id=cat(mids, np.int32),
        frames=tuple(v.frame for v in views), background=cat(bg, bool), timings=tuple(clock.items),
    )


def assign_by_majority(
    ev: MaskEvidence,
    groups: Sequence[Sequence[int]],
    min_instance_points: int = 30,
    label_support: bool = False,
) -> tuple[np.ndarray, np.ndarray]:
    """Per-voxel instances from groups of masks (indices into ``ev``).

    A voxel goes to the group with the most member masks covering it (lowest group
    index on ties); support voxels stay unlabelled unless ``label_support``. A group's
    score is its number of masks; groups holding fewer than ``min_instance_points`` raw
    points are dropped. Returns (instance (N,) int32 with ids by descending score, scores (K,)).
    """
    n = ev.points.shape[0]
    g = len(groups)
    if g == 0 or n == 0:
        return np.full(n, -1, np.int32), np.zeros(0, np.float32)
    rows = np.concatenate([np.full(len(m), i) for i, m in enumerate(groups)])
    cols = np.concatenate([np.asarray(m, np.int64) for m in groups])
    member = sp.csr_matrix((np.ones(len(cols), np.float32), (rows, cols)), shape=(g, ev.num_masks))
    votes = (member @ ev.voxels).toarray()  # (G, N) masks of each group covering each voxel
    win = np.argmax(votes, axis=0)
    has = votes[win, np.arange(n)] > 0
    if not label_support:
        has &= ~ev.support
    label = np.where(has, win, -1)
    size = np.array([len(m) for m in groups], np.float64)
    pts = np.bincount(label[label >= 0], weights=ev.counts[label >= 0], minlength=g)
    inst, alive = renumber_by_score(label, size, pts >= min_instance_points)
    return inst, size[alive].astype(np.float32)


def run_baseline(
    scene: Scene,
    method: str,
    group: Callable[[MaskEvidence], Sequence[Sequence[int]]],
    min_instance_points: int,
) -> Prediction:
    """A baseline end to end: the shared front end, the baseline's ``group``ing of the masks,
    then ``assign_by_majority``; timed per stage."""
    clock = StageClock()
    ev = mask_evidence(scene, clock=clock)
    with clock("grouping"):
        groups = group(ev)
    with clock("vote"):
        inst, scores = assign_by_majority(ev, groups, min_instance_points)
    return Prediction(ev.points, inst, scores, tuple(clock.items), method)
