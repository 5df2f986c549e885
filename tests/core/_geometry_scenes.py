"""Tiny analytic scenes for the geometry tests: a table plane z = 0 with an axis-aligned box,
ray-cast exactly into posed pinhole views (no files, no randomness)."""

from __future__ import annotations

import numpy as np

from clutt3r_core.scene import Camera, MaskCandidates, View

BOX_MIN = np.array([-0.05, -0.05, 0.0])
BOX_MAX = np.array([0.05, 0.05, 0.08])
TABLE_HALF = 0.4  # the table is a 0.8 m square, larger than any object


def look_at(eye, target=(0.0, 0.0, 0.0), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_camera of an OpenCV camera at ``eye`` looking at ``target`` (world z up)."""
    eye, target, up = (np.asarray(a, float) for a in (eye, target, up))
    f = target - eye
    f /= np.linalg.norm(f)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    d = np.cross(f, r)
    T = np.eye(4)
    T[:3, :3] = np.stack([r, d, f], axis=1)
    T[:3, 3] = eye
    return T


def render(cam: Camera, box: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) float32 with NaN off the table, object id (H, W) int32: 0 table, 1 box, -1 none)."""
    vs, us = np.mgrid[0 : cam.height, 0 : cam.width]
    dirs_c = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones_like(us, float)], -1).reshape(-1, 3)
    R, o = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    d = dirs_c @ R.T  # t along d is the z-depth, since d has unit camera z
    with np.errstate(divide="ignore", invalid="ignore"):
        t_tab = -o[2] / d[:, 2]
        hit = o + t_tab[:, None] * d
        on_tab = (t_tab > 0) & (np.abs(hit[:, 0]) <= TABLE_HALF) & (np.abs(hit[:, 1]) <= TABLE_HALF)
        t = np.where(on_tab, t_tab, np.inf)
        ids = np.where(on_tab, 0, -1)
        if box:
            t1 = (BOX_MIN - o) / d
            t2 = (BOX_MAX - o) / d
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            bh = (tn <= tf) & (tn > 0) & (tn < t)
            t = np.where(bh, tn, t)
            ids = np.where(bh, 1, ids)
    depth = np.where(np.isfinite(t), t, np.nan).astype(np.float32)
    return depth.reshape(cam.height, cam.width), ids.reshape(cam.height, cam.width).astype(np.int32)


EYES = ((0.35, 0.0, 0.45), (-0.2, 0.3, 0.45), (-0.2, -0.3, 0.5))


def make_views(n: int = 2, width: int = 160, height: int = 120, f: float = 200.0, box: bool = True) -> list[View]:
    """``n`` (<= 3) views of the table + box scene; the masks of each view are [box, table]."""
    views = []
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    for i, eye in enumerate(EYES[:n]):
        cam = Camera(K, width, height, look_at(eye))
        depth, ids = render(cam, box)
        rgb = np.zeros((height, width, 3), np.uint8)
        rgb[ids == 0] = (200, 200, 200)
        rgb[ids == 1] = (200, 30, 30)
        masks = MaskCandidates(np.stack([ids == 1, ids == 0]), np.array([1, 2], np.int32))
        views.append(View(frame=i, rgb=rgb, camera=cam, depth=depth, masks=masks, name=f"synthetic {i}"))
    return views
