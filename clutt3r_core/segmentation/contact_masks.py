"""Per-point mask evidence for the contact fill (ours, issue 13 part 2, session 9).

The contact fill (``refine.contact_labels``, ``contact_fill_low`` / ``contact_fill_high``) gives an
unlabelled point near an object's foot the object's label from geometry alone: near the object,
a few millimetres above its own support level. On generated scenes those points are the object's
lowest walls; on the real sample_seq4 they were mostly tray-floor noise around the objects (11 %
of them inside their new instance's candidate masks against 35 % for its own points at the same
heights). The masks say which: a wall point projects inside the object's masks in the views that
see it, a floor point beside the object projects beside them.

``point_mask_votes`` counts, for each point and the instance it would join, the views where the
point projects inside the image and the view's depth agrees with it (it is seen, not hidden behind
something nearer and not floating in front of the measured surface), and of those the views where
its pixel lies in a mask of that instance's group (``vote.instance_group`` -> the group's nodes ->
their candidate masks). No voxel provenance (``FusedCloud.pixel_voxel``) is used: the fill's
points may be rim voxels or points the surface estimate moved, which no pixel fed as they stand.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Camera, MaskCandidates

__all__ = ["MaskViews", "PointMaskVotes", "mask_views", "point_mask_votes"]


@dataclass(frozen=True, eq=False)
class MaskViews:
    """The views in which a point's masks are read.

    Attributes:
        cameras: V cameras (``Camera``: intrinsics, size, camera-to-world pose).
        depths: V (H_v, W_v) float32 z-depth in metres, NaN = hole (the views' own depth).
        codes: V (H_v, W_v) int mask-set index of every pixel (``MaskCandidates.codes``).
        code_instance: V (C_v, K) bool: mask set c of view v holds a mask of instance k.
    """

    cameras: tuple[Camera, ...]
    depths: tuple[np.ndarray, ...]
    codes: tuple[np.ndarray, ...]
    code_instance: tuple[np.ndarray, ...]

    def __post_init__(self) -> None:
        v = len(self.cameras)
        if not (len(self.depths) == len(self.codes) == len(self.code_instance) == v):
            raise SceneError("MaskViews: cameras, depths, codes and code_instance must have one entry per view")
        ks = {ci.shape[1] for ci in self.code_instance}
        if len(ks) > 1:
            raise SceneError(f"MaskViews: code_instance must have the same K columns in every view, got {sorted(ks)}")
        for i, (cam, d, c, ci) in enumerate(zip(self.cameras, self.depths, self.codes, self.code_instance)):
            hw = (cam.height, cam.width)
            if d.shape != hw or c.shape != hw:
                raise SceneError(f"MaskViews: view {i}'s depth {d.shape} and codes {c.shape} must be {hw}")
            if ci.ndim != 2 or ci.dtype != bool:
                raise SceneError(f"MaskViews: view {i}'s code_instance must be (C, K) bool")
            if c.size and ci.shape[0] <= int(c.max()):
                raise SceneError(f"MaskViews: view {i}'s codes reach {int(c.max())} but only {ci.shape[0]} sets")

    @property
    def num_instances(self) -> int:
        return self.code_instance[0].shape[1] if self.code_instance else 0


def mask_views(cameras: Sequence[Camera], depths: Sequence[np.ndarray | None], masks: Sequence[MaskCandidates],
               node_view: np.ndarray, node_instance: np.ndarray, num_instances: int) -> MaskViews:
    """``MaskViews`` from the segmentation's views and nodes.

    cameras, depths, masks: per view (canonical order), the camera, its (H, W) depth (None = no
    depth: nothing is seen there) and its candidates in node order (the pipeline's ``nodes_masks``);
    node_view: (U,) int view of every node, nodes of a view consecutive in view order (``NodeTable``);
    node_instance: (U,) int instance of every node, -1 = none (``Trace.node_instance``)."""
    node_view = np.asarray(node_view, np.int64).reshape(-1)
    node_instance = np.asarray(node_instance, np.int64).reshape(-1)
    if node_view.shape != node_instance.shape:
        raise SceneError("mask_views: node_view and node_instance must both be (U,)")
    if len(node_view) and (np.diff(node_view) < 0).any():
        raise SceneError("mask_views: the nodes of a view must be consecutive, views in order")
    cis, ds, cs = [], [], []
    for vi, (cam, depth, m) in enumerate(zip(cameras, depths, masks)):
        own = node_instance[node_view == vi]  # this view's nodes, in its candidates' order
        if len(own) != m.bits.shape[1]:
            raise SceneError(f"mask_views: view {vi} has {m.bits.shape[1]} candidates but {len(own)} nodes")
        onehot = np.zeros((len(own), num_instances), bool)
        ok = own >= 0
        onehot[np.flatnonzero(ok), own[ok]] = True
        # set c holds a mask of instance k: an integer product of the (C, M) and (M, K) 0/1 tables
        cis.append((m.bits.astype(np.int32) @ onehot.astype(np.int32)) > 0)
        hw = (cam.height, cam.width)
        ds.append(np.full(hw, np.nan, np.float32) if depth is None else np.asarray(depth, np.float32))
        cs.append(np.asarray(m.codes))
    return MaskViews(tuple(cameras), tuple(ds), tuple(cs), tuple(cis))


@dataclass(frozen=True, eq=False)
class PointMaskVotes:
    """Per point, the views that see it and those of them that put it in its instance's masks.

    Attributes:
        seen: (P,) int32 views where the point projects inside the image and the view's depth at
            its pixel is within the tolerance of the point's own depth.
        inside: (P,) int32 of those views, the ones where its pixel lies in a mask of its instance.
    """

    seen: np.ndarray
    inside: np.ndarray

    def __post_init__(self) -> None:
        if self.seen.shape != self.inside.shape or self.seen.ndim != 1:
            raise SceneError("PointMaskVotes: seen and inside must both be (P,)")
        if (self.inside > self.seen).any():
            raise SceneError("PointMaskVotes: inside counts a subset of the seen views")

    def share(self) -> np.ndarray:
        """(P,) float64 inside / seen (NaN where no view sees the point)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self.seen > 0, self.inside / np.maximum(self.seen, 1), np.nan)


def point_mask_votes(points: np.ndarray, label: np.ndarray, views: MaskViews, depth_tolerance: float,
                     margin: int = 0) -> PointMaskVotes:
    """Count the views that see each point and those that put it inside its instance's masks.

    points: (P, 3) world metres; label: (P,) int the instance each point is tested for (in
    0..K-1; -1 or K and above: no masks, never inside); depth_tolerance: metres, how far the
    view's depth at the point's pixel (nearest pixel centre) may lie from the point's own camera
    depth for the view to see it (nearer: hidden behind something; farther: the point floats in
    front of what the view measured); margin: pixels, a seen point counts as inside when any pixel
    of the (2 margin + 1)^2 square around its pixel lies in a mask of its instance (candidate
    masks' boundaries are off by a few pixels, and an object's lowest walls project onto its
    masks' boundary)."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    lab = np.asarray(label, np.int64).reshape(-1)
    if len(lab) != len(p):
        raise SceneError(f"point_mask_votes: {len(p)} points but {len(lab)} labels")
    if not depth_tolerance > 0:
        raise SceneError(f"point_mask_votes: depth_tolerance must be > 0 m, got {depth_tolerance}")
    if margin < 0:
        raise SceneError(f"point_mask_votes: margin must be >= 0 pixels, got {margin}")
    seen = np.zeros(len(p), np.int32)
    inside = np.zeros(len(p), np.int32)
    k = views.num_instances
    has = (lab >= 0) & (lab < k)
    for cam, depth, codes, ci in zip(views.cameras, views.depths, views.codes, views.code_instance):
        uv, z = cam.project(p)
        u, v = np.round(uv[:, 0]), np.round(uv[:, 1])
        ok = (z > 1e-6) & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        idx = np.flatnonzero(ok)
        ui, vi = u[idx].astype(np.int64), v[idx].astype(np.int64)
        d = depth[vi, ui]
        vis = np.abs(d - z[idx]) <= depth_tolerance  # NaN holes compare False: not seen
        idx, ui, vi = idx[vis], ui[vis], vi[vis]
        seen[idx] += 1
        h = has[idx]
        idx, ui, vi = idx[h], ui[h], vi[h]
        hit = np.zeros(len(idx), bool)
        for dv in range(-margin, margin + 1):
            for du in range(-margin, margin + 1):
                uu = np.clip(ui + du, 0, cam.width - 1)
                vv = np.clip(vi + dv, 0, cam.height - 1)
                hit |= ci[codes[vv, uu].astype(np.int64), lab[idx]]
        inside[idx] += hit
    return PointMaskVotes(seen, inside)
