"""Geometric fallback for objects no candidate mask covers (ours, session 8; off by default).

On fresh generated seeds the largest cause of objects missed at IoU 0.5 is that no view has a
candidate mask of them (docs/benchmark/strict-iou.md, "objects missed at IoU 0.5"): their
super-voxels get no vote and stay unlabelled. After the vote, the unlabelled voxels of
non-support super-voxels that no background mask covers (``max_background_cover``: the tray's walls
and depth-noise specks over the table are covered by the candidates' table / tray masks, which
``evidence.background_masks`` flagged) and that stand at least ``min_height`` above the support plane are grouped
into connected clusters (voxel centres within ``connect_radius``); a cluster with at least
``min_points`` raw points, a bounding-box side of at least ``min_extent`` and a top at least
``min_top`` above the plane becomes a new instance.

The new instances come after every voted one (ids K..K+M-1) with a confidence below every voted
instance's (``score_fraction`` of the lowest, scaled by the cluster's points relative to the
largest cluster's), so a wrong one costs AP little. They have no mask nodes: the pipeline's
``Segmentation.instance_nodes`` answers () for them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["UnvotedConfig", "UnvotedResult", "unvoted_instances"]


@dataclass(frozen=True)
class UnvotedConfig:
    """Unvoted-cluster fallback (ours, session 8)."""

    min_points: int = 0
    """Raw points a cluster needs to become an instance; 0 = off, the default. Ours, measured at 50
    (docs/benchmark/strict-iou.md, session 8 "geometric fallback"): mean AP25 / AP50 / AP tuning
    seeds 2-3 97.77 / 93.60 / 53.70 -> 98.88 / 93.60 / 53.83, check seeds 0-1 identical, fresh
    seeds 10-13 96.25 / 91.40 / 51.31 -> 98.23 / 91.40 / 51.40 (the spoon and padlock come back
    at IoU >= 0.25, not 0.5). Why it is off: on the real samples every added cluster is not an
    object (sample_seq1 33: folds of the cloth the objects lie on, fringes between objects;
    sample_seq4 17: the tray's rim, the table beside the tray, fringes), and on hard generated
    scenes most added clusters are the tray's."""
    min_extent: float = 0.02
    """Metres: the largest side of the cluster's axis-aligned bounding box must reach this (ours:
    the smallest YCB objects are >= 4 cm; depth-noise specks are a voxel or two)."""
    min_height: float = 0.01
    """Metres above the support plane for a voxel to be a candidate (ours: two 5 mm voxels, the
    supervoxels' ``plane_distance``: closer voxels are table noise)."""
    min_top: float = 0.02
    """Metres: the cluster's highest voxel must stand this far above the plane (ours)."""
    connect_radius: float = 0.0075
    """Metres: voxel centres closer than this are connected (ours: 1.5 voxels of 5 mm)."""
    max_background_cover: float = 0.5
    """A super-voxel that some background mask covers this fraction of (or more) is not a
    candidate (ours: measured on tuning seeds 2-3, the tray walls' clusters have a mean background
    cover of 0.74-1.0, the unmasked objects' 0.0-0.4; the vote's ``min_coverage``)."""
    score_fraction: float = 0.5
    """The largest cluster's confidence as a fraction of the lowest voted instance's (ours:
    below every voted instance, so its ids come after them)."""

    def __post_init__(self) -> None:
        if self.min_points < 0:
            raise SceneError(f"UnvotedConfig.min_points must be >= 0, got {self.min_points}")
        if not (self.min_extent >= 0 and self.min_height >= 0 and self.min_top >= 0 and self.connect_radius > 0):
            raise SceneError("UnvotedConfig needs min_extent, min_height, min_top >= 0 m and connect_radius > 0 m")
        if not 0 < self.max_background_cover <= 1:
            raise SceneError(f"UnvotedConfig.max_background_cover must be in (0, 1], got {self.max_background_cover}")
        if not 0 < self.score_fraction < 1:
            raise SceneError(f"UnvotedConfig.score_fraction must be in (0, 1), got {self.score_fraction}")


@dataclass(frozen=True, eq=False)
class UnvotedResult:
    """The labels with the fallback's instances added.

    Attributes:
        instance: (N,) int32 instance per voxel, -1 = none; the voted ids 0..K-1 unchanged,
            the added ones K..K+M-1 by descending raw points.
        scores: (K+M,) float32 confidences; the added ones below every voted one.
        added_points: (M,) int64 raw points of each added instance.
        added_height: (M,) float32 metres, the highest voxel of each added instance above the plane.
    """

    instance: np.ndarray
    scores: np.ndarray
    added_points: np.ndarray
    added_height: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.added_points)
        if self.added_height.shape != (m,) or len(self.scores) < m:
            raise SceneError("UnvotedResult: added_points, added_height (M,) and scores (K+M,) must agree")


def unvoted_instances(
    points: np.ndarray,
    counts: np.ndarray,
    instance: np.ndarray,
    sv_labels: np.ndarray,
    sv_support: np.ndarray,
    background_cover: np.ndarray,
    plane: np.ndarray | None,
    scores: np.ndarray,
    cfg: UnvotedConfig,
) -> UnvotedResult:
    """Add the unlabelled clusters standing above the support as instances.

    points: (N, 3) world metres (voxel centres); counts: (N,) raw points per voxel; instance:
    (N,) int voted instance, -1 = none; sv_labels: (N,) super-voxel of each voxel; sv_support:
    (Ks,) bool; background_cover: (Ks,) float, the largest occupancy o_i(k) of any background
    mask (0 when none); plane: [nx, ny, nz, d], normal towards the cameras (``SuperVoxels.plane``), or
    None (no support found: nothing is added); scores: (K,) voted confidences.
    """
    from scipy.spatial import cKDTree

    from clutt3r_core.graph_ops import connected_components

    instance = np.asarray(instance, np.int32)
    scores = np.asarray(scores, np.float32)
    none = UnvotedResult(instance, scores, np.zeros(0, np.int64), np.zeros(0, np.float32))
    if cfg.min_points <= 0 or plane is None or not len(points):
        return none
    pl = np.asarray(plane, np.float64)
    height = np.asarray(points, np.float64) @ pl[:3] + pl[3]
    free = ~np.asarray(sv_support, bool) & (np.asarray(background_cover) < cfg.max_background_cover)
    cand = np.flatnonzero((instance < 0) & free[sv_labels] & (height >= cfg.min_height))
    if not len(cand):
        return none
    p = np.asarray(points, np.float64)[cand]
    pairs = cKDTree(p).query_pairs(cfg.connect_radius, output_type="ndarray")
    comp = connected_components(len(cand), pairs[:, 0], pairs[:, 1])
    n_comp = int(comp.max()) + 1
    pts = np.bincount(comp, weights=np.asarray(counts, np.float64)[cand], minlength=n_comp).astype(np.int64)
    top = np.full(n_comp, -np.inf)
    np.maximum.at(top, comp, height[cand])
    lo, hi = np.full((n_comp, 3), np.inf), np.full((n_comp, 3), -np.inf)
    np.minimum.at(lo, comp, p)
    np.maximum.at(hi, comp, p)
    extent = (hi - lo).max(axis=1)
    keep = np.flatnonzero((pts >= cfg.min_points) & (extent >= cfg.min_extent) & (top >= cfg.min_top))
    if not len(keep):
        return none
    keep = keep[np.lexsort((keep, -pts[keep]))]  # most points first; ties by component index
    k = len(scores)
    new_id = np.full(n_comp, -1, np.int32)
    new_id[keep] = k + np.arange(len(keep), dtype=np.int32)
    out = instance.copy()
    out[cand] = new_id[comp]
    floor = float(scores.min()) if k else 1.0
    added = (cfg.score_fraction * floor * pts[keep] / pts[keep[0]]).astype(np.float32)
    return UnvotedResult(out, np.concatenate([scores, added]), pts[keep], top[keep].astype(np.float32))
