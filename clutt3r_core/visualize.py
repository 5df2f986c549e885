"""Pictures of results: instances splatted into the views, for people who look before they read."""

from __future__ import annotations

from typing import Callable

import numpy as np

from clutt3r_core.scene import Scene, View

__all__ = ["instance_palette", "instance_overlay", "overview_sheet"]

_FLOAT_RANKS = 2**24
"""Depth ranks below this are exact in float32, so OpenCV's erosion can take their minimum."""


def instance_palette(n: int, seed: int = 7) -> np.ndarray:
    """(n, 3) uint8 well-separated colours (golden-ratio hues), stable for a given n."""
    import cv2

    hues = (np.arange(n) * 0.618033988749895 * 180 + seed) % 180
    hsv = np.stack([hues, np.full(n, 200), np.full(n, 255)], axis=1).astype(np.uint8)[None]
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0] if n else np.zeros((0, 3), np.uint8)


def instance_overlay(points: np.ndarray, instance: np.ndarray, view: View, alpha: float = 0.6,
                     radius: int = 0) -> np.ndarray:
    """(H, W, 3) uint8: the view's RGB with labelled points splatted in instance colours.

    Each point covers the (2r+1) x (2r+1) pixel square around its projection (r: half a
    5 mm voxel in pixels at the median depth, at least ``radius``), z-buffered (nearest
    wins) so hidden instances do not paint over visible ones; a pixel whose nearest point
    is unlabelled keeps its colour.

    Computed as a z-buffer of the projections (each pixel's nearest point) followed by a
    minimum filter of the points' depth ranks over the square (OpenCV's erosion, over the box
    of pixels the projections can reach): the same winner as splatting every point at every
    offset (which took 2 s per 1080p view; issue 13). The winners' instances are then read
    through one table lookup, so only the labelled pixels are handled one by one (on
    sample_seq4 1080p: 0.25 M of the 2 M pixels a point reaches).
    """
    cam = view.camera
    lab = instance >= 0
    if not lab.any():
        return view.rgb.copy()
    uv, z = cam.project(points)
    r = max(radius, int(np.ceil(cam.fx * 0.005 / max(np.median(z[z > 0]) if (z > 0).any() else 1.0, 1e-3) / 2)))
    H, W = cam.height, cam.width
    # projections that can reach the image: on the canvas padded by r on each side
    with np.errstate(invalid="ignore"):
        near = (z > 0) & (uv[:, 0] > -r - 1) & (uv[:, 0] < W + r) & (uv[:, 1] > -r - 1) & (uv[:, 1] < H + r)
    idx = np.flatnonzero(near)
    u = np.round(uv[idx, 0]).astype(np.int64) + r
    v = np.round(uv[idx, 1]).astype(np.int64) + r
    ok = (u >= 0) & (u < W + 2 * r) & (v >= 0) & (v < H + 2 * r)
    idx, u, v = idx[ok], u[ok], v[ok]
    if not len(idx):
        return view.rgb.copy()
    # rank 0 = nearest point; the canvas holds each cell's smallest rank (len(idx) = none)
    nearest_first = np.argsort(z[idx], kind="stable")
    by_depth = idx[nearest_first]
    none = len(idx)
    # only the box of image pixels whose square can reach a projection is filtered (padded
    # canvas: image pixel (y, x) takes the minimum over canvas rows y..y+2r, columns x..x+2r)
    y0, y1 = max(int(v.min()) - 2 * r, 0), min(int(v.max()), H - 1)
    x0, x1 = max(int(u.min()) - 2 * r, 0), min(int(u.max()), W - 1)
    if y0 > y1 or x0 > x1:
        return view.rgb.copy()
    bh, bw = y1 - y0 + 1, x1 - x0 + 1
    Wb = bw + 2 * r
    cell = ((v - y0) * Wb + (u - x0))[nearest_first]
    # each cell's smallest rank (its nearest point): an unbuffered minimum, not np.unique's
    # second sort (0.7 vs 8.6 ms for 157 k points; the same ranks); float32 holds every rank
    # below _FLOAT_RANKS exactly, for OpenCV's erosion
    dtype = np.float32 if none < _FLOAT_RANKS else np.int64
    canvas = np.full((bh + 2 * r) * Wb, none, dtype)
    np.minimum.at(canvas, cell, np.arange(none, dtype=dtype))
    canvas = canvas.reshape(bh + 2 * r, Wb)
    if none < _FLOAT_RANKS:
        # OpenCV's erosion of a rectangle is the same minimum, far faster than numpy passes
        # (r is 15 px at 1080p, 0.24 m)
        import cv2

        win = cv2.erode(canvas, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_REPLICATE)
        win = win[r : r + bh, r : r + bw]
    else:
        # separable minimum over the (2r+1)^2 square: along u, then along v
        rows = canvas[:, 0:bw].copy()
        for d in range(1, 2 * r + 1):
            np.minimum(rows, canvas[:, d : d + bw], out=rows)
        win = rows[0:bh].copy()
        for d in range(1, 2 * r + 1):
            np.minimum(win, rows[d : d + bh], out=win)
    # each box pixel's instance through its winner's rank (a table lookup over the box); only
    # pixels whose nearest point is labelled are painted, the others stay as they are
    label_of = np.full(none + 1, -1, np.int32)
    label_of[:none] = instance[by_depth]
    ids = np.take(label_of, win.astype(np.intp)).reshape(-1)
    hit = np.flatnonzero(ids >= 0)
    ids = ids[hit]
    hy, hx = np.divmod(hit, bw)
    pix = (hy + y0) * W + (hx + x0)
    pal = instance_palette(int(instance.max()) + 1).astype(np.float32)
    # the blend (float32, truncated to uint8) of every (instance, channel, value), looked up per
    # painted pixel: the same numbers as blending each pixel, without its float passes
    lut = np.clip((1 - alpha) * np.arange(256, dtype=np.float32) + alpha * pal[:, :, None], 0, 255).astype(np.uint8)
    out = view.rgb.copy()
    flat = out.reshape(-1, 3)
    at = (ids[:, None] * 3 + np.arange(3)) * 256 + flat[pix]
    flat[pix] = np.take(lut.reshape(-1), at)
    return out


def overview_sheet(points: np.ndarray, instance: np.ndarray, scene: Scene, max_views: int = 4,
                   width: int = 480, map: Callable = map) -> np.ndarray:  # noqa: A002
    """Up to ``max_views`` initial views with instance overlays, tiled in a row, ``width`` px each.

    ``map``: how the tiles are drawn, e.g. a thread pool's ``map`` (numpy and OpenCV release
    the GIL for most of a tile; the ``clutt3r segment`` command draws them beside ``save_run``).
    """
    views = sorted(scene.initial_views, key=lambda v: v.frame)
    pick = np.linspace(0, len(views) - 1, min(max_views, len(views))).round().astype(int)
    return np.concatenate(list(map(lambda i: _tile(points, instance, views[i], width), pick)), axis=1)


def _tile(points: np.ndarray, instance: np.ndarray, view: View, width: int) -> np.ndarray:
    import cv2

    ov = instance_overlay(points, instance, view)
    h = int(round(ov.shape[0] * width / ov.shape[1]))
    return cv2.resize(ov, (width, h), interpolation=cv2.INTER_AREA)
