"""Pictures of results: instances splatted into the views, for people who look before they read."""

from __future__ import annotations

import numpy as np

from clutt3r_core.scene import Scene, View

__all__ = ["instance_palette", "instance_overlay", "overview_sheet"]


def instance_palette(n: int, seed: int = 7) -> np.ndarray:
    """(n, 3) uint8 well-separated colours (golden-ratio hues), stable for a given n."""
    import cv2

    hues = (np.arange(n) * 0.618033988749895 * 180 + seed) % 180
    hsv = np.stack([hues, np.full(n, 200), np.full(n, 255)], axis=1).astype(np.uint8)[None]
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0] if n else np.zeros((0, 3), np.uint8)


def instance_overlay(points: np.ndarray, instance: np.ndarray, view: View, alpha: float = 0.6,
                     radius: int = 0) -> np.ndarray:
    """(H, W, 3) uint8: the view's RGB with labelled points splatted in instance colours.

    Points are z-buffered (nearest wins) so hidden instances do not paint over visible ones.
    """
    cam = view.camera
    img = view.rgb.astype(np.float32)
    lab = instance >= 0
    if not lab.any():
        return view.rgb.copy()
    uv, z = cam.project(points)
    u = np.round(uv[:, 0]).astype(np.int64)
    v = np.round(uv[:, 1]).astype(np.int64)
    r = max(radius, int(np.ceil(cam.fx * 0.005 / max(np.median(z[z > 0]) if (z > 0).any() else 1.0, 1e-3) / 2)))
    H, W = cam.height, cam.width
    zbuf = np.full(H * W, np.inf)
    idbuf = np.full(H * W, -2, np.int64)
    order = np.argsort(-z)  # far first, near last overwrites
    for du in range(-r, r + 1):
        for dv in range(-r, r + 1):
            uu, vv = u + du, v + dv
            ok = (z > 0) & (uu >= 0) & (uu < W) & (vv >= 0) & (vv < H)
            o = order[ok[order]]
            flat = vv[o] * W + uu[o]
            closer = z[o] < zbuf[flat]
            zbuf[flat[closer]] = z[o][closer]
            idbuf[flat[closer]] = instance[o][closer]
    # pixels whose nearest point is unlabelled stay as they are
    pal = instance_palette(int(instance.max()) + 1).astype(np.float32)
    hit = idbuf >= 0
    flat_img = img.reshape(-1, 3)
    flat_img[hit] = (1 - alpha) * flat_img[hit] + alpha * pal[idbuf[hit]]
    return np.clip(flat_img.reshape(H, W, 3), 0, 255).astype(np.uint8)


def overview_sheet(points: np.ndarray, instance: np.ndarray, scene: Scene, max_views: int = 4,
                   width: int = 480) -> np.ndarray:
    """Up to ``max_views`` initial views with instance overlays, tiled in a row, ``width`` px each."""
    import cv2

    views = sorted(scene.initial_views, key=lambda v: v.frame)
    pick = np.linspace(0, len(views) - 1, min(max_views, len(views))).round().astype(int)
    tiles = []
    for i in pick:
        ov = instance_overlay(points, instance, views[i])
        h = int(round(ov.shape[0] * width / ov.shape[1]))
        tiles.append(cv2.resize(ov, (width, h), interpolation=cv2.INTER_AREA))
    return np.concatenate(tiles, axis=1)
