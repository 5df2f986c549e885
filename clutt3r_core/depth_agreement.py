"""How much the views of a scene disagree about where the surface is, measured from the depth
itself (ours, issue 13).

The fusion (``pointcloud.fuse_views`` with ``PointCloudConfig.surface = "auto"``) runs the multi-view
surface estimate (``clutt3r_core.surface``) only when the views disagree by at least
``PointCloudConfig.surface_auto_sigma``. One depth map alone cannot tell: a camera that smooths its
depth (both real samples: 5x5 plane-fit residual 0.30 / 0.35 mm, as low as clean rendered depth)
still disagrees with the other views by 4-5.5 mm through correlated noise and pose error, which is
what thickens the fused surface. Sampling each view into the others measures exactly that.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import View

__all__ = ["DepthAgreement", "depth_disagreement"]


@dataclass(frozen=True)
class DepthAgreement:
    """How much the views disagree about where the surface is (``depth_disagreement``).

    Attributes:
        sigma: metres, the depth noise of one view as the views' disagreement shows it: the robust
            spread (1.4826 x median absolute deviation) of the depth differences between a view's
            samples and another view's depth there, over sqrt(2) (two views' errors add). It holds
            every error that makes the fused surface thick: white and correlated sensor noise,
            depth quantisation, pose and calibration error. NaN when no pair of views overlaps.
        pairs: the (sample, other view) depth differences it was measured on.
    """

    sigma: float
    pairs: int

    def __post_init__(self) -> None:
        if self.pairs < 0 or not (np.isnan(self.sigma) or self.sigma >= 0):
            raise SceneError(f"DepthAgreement needs sigma >= 0 (or NaN) and pairs >= 0, got {self.sigma}, {self.pairs}")


def _bilinear(z: np.ndarray, v: np.ndarray, u: np.ndarray, max_step: float) -> np.ndarray:
    """(M,) depth of ``z`` (H, W) at sub-pixel rows ``v`` and columns ``u`` inside [0, H-1] x [0, W-1],
    bilinear over the 4 nearest pixels; NaN where one is a hole or they span more than ``max_step``
    metres (a depth edge: no surface to interpolate)."""
    h, w = z.shape
    v0 = np.minimum(v.astype(np.intp), h - 2)
    u0 = np.minimum(u.astype(np.intp), w - 2)
    fv = (v - v0).astype(np.float32)
    fu = (u - u0).astype(np.float32)
    q = [z[v0, u0], z[v0, u0 + 1], z[v0 + 1, u0], z[v0 + 1, u0 + 1]]
    with np.errstate(invalid="ignore"):
        span = np.maximum.reduce(q) - np.minimum.reduce(q)  # NaN where a hole is among them
        out = (q[0] * (1 - fu) + q[1] * fu) * (1 - fv) + (q[2] * (1 - fu) + q[3] * fu) * fv
        return np.where(span <= max_step, out, np.nan)


def depth_disagreement(
    views: Sequence[View],
    strides: Sequence[int],
    truncation: float = 0.015,
    min_depth: float = 0.05,
    max_depth: float = 3.0,
    samples_per_view: int = 3000,
) -> DepthAgreement:
    """How much the views disagree about the surface (``DepthAgreement``), measured from the data.

    ``samples_per_view`` pixels spread evenly over each view's valid sampled depth are moved into
    every other view and compared with its depth there (bilinear, not across depth edges); only
    differences within +-``truncation`` metres count (beyond it the other view sees another
    surface: an occlusion). Every ordered pair of views is used, so the result does not depend on
    the views' order. About 50k depth reads at 8 views: a few tens of milliseconds.
    """
    grids = []
    for view, s in zip(views, strides):
        z = np.asarray(view.depth, np.float32)[::s, ::s]
        grids.append((view.camera, s, np.where((z >= min_depth) & (z <= max_depth), z, np.float32(np.nan))))
    diffs = []
    T = float(truncation)
    for a, (cam_a, sa, za) in enumerate(grids):
        ok = np.flatnonzero(np.isfinite(za).ravel())
        if not len(ok):
            continue
        pick = ok[np.linspace(0, len(ok) - 1, min(samples_per_view, len(ok))).astype(np.intp)]
        row, col = np.divmod(pick, za.shape[1])
        d = za.reshape(-1)[pick].astype(np.float64)
        pw = cam_a.pixels_to_world(col * sa, row * sa, d)
        for b, (cam_b, sb, zb) in enumerate(grids):
            if b == a:
                continue
            Tcw = cam_b.T_camera_world
            q = pw @ Tcw[:3, :3].T + Tcw[:3, 3]
            q = q[q[:, 2] > min_depth]
            u = (q[:, 0] / q[:, 2] * cam_b.fx + cam_b.cx) / sb
            v = (q[:, 1] / q[:, 2] * cam_b.fy + cam_b.cy) / sb
            inside = (u >= 0) & (u <= zb.shape[1] - 1) & (v >= 0) & (v <= zb.shape[0] - 1)
            diff = _bilinear(zb, v[inside], u[inside], T) - q[inside, 2]
            diffs.append(diff[np.abs(diff) <= T])  # NaN compares False
    dd = np.concatenate(diffs) if diffs else np.zeros(0)
    if not len(dd):
        return DepthAgreement(float("nan"), 0)
    mad = float(np.median(np.abs(dd - np.median(dd))))
    return DepthAgreement(float(1.4826 * mad / np.sqrt(2.0)), len(dd))

