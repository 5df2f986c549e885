"""Projection of stored points into a new view: z-buffered splats, silhouettes, IoU.

A stored point stands for one voxel (5 mm, Sec. IV), so it is splatted as a square of
half-size ``ceil(scale * voxel * f / z / 2)`` pixels; neighbouring points then close the
silhouette without a mesh. The z-buffer keeps the nearest point per pixel
(``np.minimum.at``: exact whatever the order of duplicates): an instance's *visible*
projection is the set of pixels it wins (occlusion by the other instances).

Work is done in the window of the image that the splats touch (``Splats``), so the cost
follows the object's size, not the image's.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from clutt3r_core.scene import Camera

__all__ = ["OCCLUSION_MARGIN", "splat_radius", "Splats", "splat_inputs", "splat", "render_labels", "silhouette", "mask_iou"]

OCCLUSION_MARGIN = 0.01
"""Metres: a point counts as in front of an occluder unless it is this much behind it (ours:
two voxels, so that touching objects do not hide each other's contact rims)."""

_MAX_RADIUS = 12
"""Ours: splats are capped at 25x25 px (a 5 mm voxel closer than ~8 cm to a 400 px camera)."""


def splat_radius(z: np.ndarray, camera: Camera, voxel: float, scale: float = 1.0) -> np.ndarray:
    """(N,) int64 half-size in pixels of each point's splat at camera depth z (metres)."""
    f = 0.5 * (camera.fx + camera.fy)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.ceil(scale * voxel * f / np.maximum(z, 1e-6) / 2.0)
    return np.clip(np.nan_to_num(r, nan=0.0), 0, _MAX_RADIUS).astype(np.int64)


@dataclass(frozen=True, eq=False)
class Splats:
    """The z-buffer of a point set inside an image window.

    Attributes:
        v0, u0, h, w: the window (rows v0..v0+h-1, columns u0..u0+w-1); h = w = 0 when no
            point lands in the image.
        zbuf: (h, w) float64 nearest camera z per pixel, inf where none.
        point: (h, w) int64 index of the nearest point, -1 where none (all -1 when made
            ``with_points=False``).
        centre: (N,) int64 flat index into the window of each point's centre pixel, -1 when
            the point is behind the camera or its centre is outside the image.
        z: (N,) float64 camera z of each point.
        radius: (N,) int64 splat half-size of each point.
    """

    v0: int
    u0: int
    h: int
    w: int
    zbuf: np.ndarray
    point: np.ndarray
    centre: np.ndarray
    z: np.ndarray
    radius: np.ndarray

    def crop(self, image: np.ndarray) -> np.ndarray:
        """The window of a full (H, W, ...) image."""
        return image[self.v0 : self.v0 + self.h, self.u0 : self.u0 + self.w]

    def visible(self, occluder_depth: np.ndarray | None = None, margin: float = OCCLUSION_MARGIN) -> np.ndarray:
        """(N,) bool: points whose centre pixel is in the window and that are not behind the
        z-buffer (nor a full (H, W) ``occluder_depth``, camera z) by more than ``margin`` metres."""
        if not (self.h and self.w):
            return np.zeros(len(self.centre), bool)
        cf = np.maximum(self.centre, 0)
        vis = (self.centre >= 0) & (self.z <= self.zbuf.reshape(-1)[cf] + margin)
        if occluder_depth is not None:
            vis &= self.z <= self.crop(occluder_depth).reshape(-1)[cf] + margin
        return vis

    def silhouette(self, occluder_depth: np.ndarray | None = None, margin: float = OCCLUSION_MARGIN) -> np.ndarray:
        """(h, w) bool window pixels covered by a splat whose nearest point is not behind a full
        (H, W) ``occluder_depth`` (camera z) by more than ``margin`` metres."""
        local = np.isfinite(self.zbuf)
        if occluder_depth is not None and self.h and self.w:
            local &= self.zbuf <= self.crop(occluder_depth) + margin
        return local

    def paste(self, local: np.ndarray, full_shape: tuple[int, int], fill) -> np.ndarray:
        out = np.full(full_shape, fill, dtype=local.dtype)
        out[self.v0 : self.v0 + self.h, self.u0 : self.u0 + self.w] = local
        return out


_RANK_LIMIT = 1 << 24
"""Ranks below 2^24 are exact in float32 (``_zbuf_by_filter``); more points filter the z itself."""


def _zbuf_by_filter(z: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray, idx: np.ndarray,
                    u0: int, v0: int, h: int, w: int) -> np.ndarray:
    """(h * w,) nearest z per window pixel, the same values as the per-offset z-buffer of
    ``splat``: per splat radius, the nearest z at each centre pixel (window padded by the
    radius, so splats centred outside it still reach in) then a (2r+1)^2 minimum filter
    (a square splat of half-size r covers exactly the pixels within r in both axes).

    The filter is OpenCV's erosion with a square kernel and an inf border: the same values as
    ``scipy.ndimage.minimum_filter(..., mode="constant", cval=inf)`` (a minimum is exact;
    tests/core/update/test_pose_speed.py compares them), ~3x less CPU on the pose fit's windows.
    It runs on each point's rank in z order, in float32 (exact below 2^24 points), and the
    minimum rank over the radius groups maps back to its z once: the minimum of ranks is the
    rank of the minimum, so the z-buffer is the same float64 values. OpenCV's float32 erosion is
    ~4x faster than its float64 one (measured on the pose fit's ~130x150 windows, where these
    filters were a third of a splat's CPU)."""
    import cv2

    zi = z[idx]
    ranked = len(zi) < _RANK_LIMIT
    if ranked:
        # any sort order: points of equal z get distinct ranks, but every rank maps back to the
        # same z (the default sort is ~2x faster than the stable one on the fit's ~600 points)
        order = np.argsort(zi)
        key = np.empty(len(zi), np.float32)
        key[order] = np.arange(len(zi), dtype=np.float32)
    else:
        key = zi
    # "no point" is the rank n (above every rank, exact in float32), so the ranks map back to
    # z through one lookup with inf appended; the unranked path keeps inf
    empty = float(len(zi)) if ranked else np.inf
    ri, ui, vi = r[idx], u[idx] - u0, v[idx] - v0
    best = np.full((h, w), empty, key.dtype)
    rmin = int(ri.min())
    counts = np.bincount(ri - rmin)
    for k in np.flatnonzero(counts):
        rr = int(k) + rmin
        g = np.flatnonzero(ri == rr) if len(counts) > 1 else slice(None)
        uu, vv = ui[g] + rr, vi[g] + rr
        ph, pw = h + 2 * rr, w + 2 * rr
        inside = (uu >= 0) & (uu < pw) & (vv >= 0) & (vv < ph)  # the rest cannot reach the window
        cz = np.full(ph * pw, empty, key.dtype)
        np.minimum.at(cz, vv[inside] * pw + uu[inside], key[g][inside])
        er = cv2.erode(cz.reshape(ph, pw), _square(rr), borderType=cv2.BORDER_CONSTANT, borderValue=empty)
        np.minimum(best, er[rr : rr + h, rr : rr + w], out=best)
    if not ranked:
        return best.reshape(-1)
    return np.append(zi[order], np.inf)[best.reshape(-1).astype(np.int64)]


@functools.cache
def _square(r: int) -> np.ndarray:
    """(2r+1, 2r+1) uint8 ones: the erosion / dilation kernel of a splat of half-size r, cached."""
    return np.ones((2 * r + 1, 2 * r + 1), np.uint8)


def _may_win(zbuf: np.ndarray, z: np.ndarray, u: np.ndarray, v: np.ndarray, r: np.ndarray, idx: np.ndarray,
             u0: int, v0: int) -> np.ndarray:
    """(len(idx),) bool: points ``idx`` whose z equals the largest z-buffer value over their splat
    within the (h, w) window ``zbuf`` (every value there is <= their z, so equality means they
    are the nearest at some pixel). Maximum filter per splat radius, -inf outside the window."""
    import cv2

    h, w = zbuf.shape
    out = np.zeros(len(idx), bool)
    ri = r[idx]
    for rr in np.unique(ri):
        sel = np.flatnonzero(ri == rr)
        g = idx[sel]
        rr = int(rr)
        pad = np.pad(zbuf, rr, constant_values=-np.inf)
        zz = cv2.dilate(pad, _square(rr), borderType=cv2.BORDER_CONSTANT, borderValue=-np.inf)
        uu, vv = u[g] - u0 + rr, v[g] - v0 + rr
        inside = (uu >= 0) & (uu < w + 2 * rr) & (vv >= 0) & (vv < h + 2 * rr)
        hit = np.zeros(len(g), bool)
        hit[inside] = zz[vv[inside], uu[inside]] == z[g][inside]
        out[sel] = hit
    return out


def splat_inputs(points: np.ndarray, camera: Camera, voxel: float, scale: float = 1.0,
                 window: tuple[int, int, int, int] | None = None):
    """What ``splat`` splats: (z (N,) camera depth, u, v (N,) int64 pixel centres, r (N,) int
    splat radii, ok (N,) bool in front of the camera and touching the image, (v0, u0, h, w) the
    window: the one given, else the one the ``ok`` splats touch, empty without any)."""
    # Camera.project and splat_radius written out with the same operations in the same order
    # (bit-identical u, v, z, r: tests/core/update/test_pose_speed.py), without their per-call
    # overhead (the (N, 2) stack, errstate, nan_to_num of values that are
    # never NaN here): the pose fit splats ~100 times per fit, this was 1/5 of a splat's CPU.
    T = camera.T_camera_world  # computed once per camera (Camera caches it)
    pc = np.asarray(points, dtype=np.float64).reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uf = camera.fx * pc[:, 0] / z + camera.cx
        vf = camera.fy * pc[:, 1] / z + camera.cy
        ok = np.isfinite(z) & (z > 1e-6) & np.isfinite(uf) & np.isfinite(vf)
        u = np.round(np.where(ok, uf, 0)).astype(np.int64)
        v = np.round(np.where(ok, vf, 0)).astype(np.int64)
        # splat_radius of where(ok, z, inf): those z are > 1e-6 (no maximum needed) or inf (r = 0)
        # and never NaN (no nan_to_num); radii are >= 0, so only the upper clip can act
        f = 0.5 * (camera.fx + camera.fy)
        r = np.minimum(np.ceil(scale * voxel * f / np.where(ok, z, np.inf) / 2.0), _MAX_RADIUS).astype(np.int64)
    H, W = camera.height, camera.width
    ok &= (u + r >= 0) & (u - r < W) & (v + r >= 0) & (v - r < H)
    if window is not None:
        return z, u, v, r, ok, tuple(window)
    if not ok.any():
        return z, u, v, r, ok, (0, 0, 0, 0)
    v0, v1 = max(0, int((v - r)[ok].min())), min(H, int((v + r)[ok].max()) + 1)
    u0, u1 = max(0, int((u - r)[ok].min())), min(W, int((u + r)[ok].max()) + 1)
    return z, u, v, r, ok, (v0, u0, v1 - v0, u1 - u0)


def splat(points: np.ndarray, camera: Camera, voxel: float, scale: float = 1.0,
          window: tuple[int, int, int, int] | None = None, with_points: bool = True) -> Splats:
    """Z-buffer (N, 3) world points in ``camera`` (in the window they touch, or ``window``).

    ``with_points=False``: the z-buffer only (``Splats.point`` is all -1), by minimum filters
    per splat radius (``_zbuf_by_filter``: the same ``zbuf``, 2-4x less CPU for the pose fit's
    hundreds of splats per object on 640x480 views; ours, measured on sample_seq1)."""
    z, u, v, r, ok, (v0, u0, h, w) = splat_inputs(points, camera, voxel, scale, window)
    n = len(z)
    u1, v1 = u0 + w, v0 + h
    centre = np.full(n, -1, np.int64)
    cin = ok & (u >= u0) & (u < u1) & (v >= v0) & (v < v1)
    centre[cin] = (v[cin] - v0) * w + (u[cin] - u0)
    idx = np.flatnonzero(ok)
    # without points the point buffer is a read-only view of -1 (the fit's splats never read it)
    pbuf = np.full(h * w, -1, np.int64) if with_points else np.broadcast_to(np.int64(-1), (h * w,))
    if len(idx) and h and w and not with_points:
        zbuf = _zbuf_by_filter(z, u, v, r, idx, u0, v0, h, w)
    elif not (len(idx) and h and w):
        zbuf = np.full(h * w, np.inf)
    else:
        # only points that win a pixel (or tie for it) write the point buffer; the z-buffer by
        # filters says which: a point's z is the maximum of the z-buffer over its splat exactly
        # when it is the nearest somewhere. The others are dropped before the per-offset
        # expansion (same winners, same order; ~1/4 of a whole scene's points on sample_seq1)
        zbuf = _zbuf_by_filter(z, u, v, r, idx, u0, v0, h, w)
        idx = idx[_may_win(zbuf.reshape(h, w), z, u, v, r, idx, u0, v0)]
        rmax = int(r[idx].max()) if len(idx) else 0
        d = np.arange(-rmax, rmax + 1)
        dv, du = (a.ravel() for a in np.meshgrid(d, d, indexing="ij"))
        reach = np.maximum(np.abs(du), np.abs(dv))
        uu = u[idx, None] + du[None, :] - u0
        vv = v[idx, None] + dv[None, :] - v0
        sel = (r[idx, None] >= reach[None, :]) & (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
        flat = (vv * w + uu)[sel]
        zz = np.broadcast_to(z[idx, None], sel.shape)[sel]
        pi = np.broadcast_to(idx[:, None], sel.shape)[sel]
        win = zz == zbuf[flat]
        pbuf[flat[win]] = pi[win]
    return Splats(v0, u0, h, w, zbuf.reshape(h, w), pbuf.reshape(h, w), centre, np.where(ok, z, np.inf), r)


def render_labels(
    points: np.ndarray, labels: np.ndarray, camera: Camera, voxel: float, scale: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer labelled world points into the camera.

    Returns (label (H, W) int32 of the nearest point, -1 where none; depth (H, W) float32 camera
    z of that point in metres, inf where none).
    """
    s = splat(points, camera, voxel, scale)
    shape = (camera.height, camera.width)
    lab_local = np.where(s.point >= 0, np.asarray(labels)[np.maximum(s.point, 0)], -1).astype(np.int32) \
        if s.h and s.w else np.zeros((0, 0), np.int32)
    return s.paste(lab_local, shape, -1), s.paste(s.zbuf.astype(np.float32), shape, np.inf)


def silhouette(
    points: np.ndarray,
    camera: Camera,
    voxel: float,
    occluder_depth: np.ndarray | None = None,
    scale: float = 1.0,
    margin: float = OCCLUSION_MARGIN,
) -> np.ndarray:
    """(H, W) bool: pixels covered by a splat of ``points`` whose nearest point is not behind
    ``occluder_depth`` (camera z of other objects, inf = none) by more than ``margin`` metres.
    (If the nearest point of a pixel is hidden, every point of that pixel is.)"""
    s = splat(points, camera, voxel, scale, with_points=False)
    return s.paste(s.silhouette(occluder_depth, margin), (camera.height, camera.width), False)


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    """IoU of two boolean masks of one shape (0 when both are empty)."""
    inter = np.count_nonzero(a & b)
    union = np.count_nonzero(a | b)
    return float(inter / union) if union else 0.0
