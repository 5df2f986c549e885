"""A tiny analytic tabletop for the mask tests: a table plane z = 0 with axis-aligned boxes,
ray-cast exactly into a posed pinhole view (no files, no randomness)."""

from __future__ import annotations

import numpy as np

from clutt3r_core.scene import Camera, View
from tests.core._geometry_scenes import look_at

# two boxes touching along x = 0, different heights and colours, and one apart
BOXES = (
    (np.array([-0.08, -0.04, 0.0]), np.array([0.0, 0.04, 0.10]), (200, 40, 40)),
    (np.array([0.0, -0.04, 0.0]), np.array([0.07, 0.04, 0.06]), (40, 60, 200)),
    (np.array([-0.05, 0.12, 0.0]), np.array([0.02, 0.18, 0.05]), (40, 180, 60)),
)


def box_view(eye=(0.05, -0.45, 0.5), width: int = 320, height: int = 240, f: float = 300.0,
             boxes=BOXES, frame: int = 0) -> tuple[View, np.ndarray]:
    """(view without masks, (H, W) int32 object id: -1 table, k box k)."""
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    cam = Camera(K, width, height, look_at(eye, target=(0.0, 0.05, 0.03)))
    vs, us = np.mgrid[0:height, 0:width]
    dirs = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones_like(us, float)], -1).reshape(-1, 3)
    R, o = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    d = dirs @ R.T  # unit camera z: t is the z-depth
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -o[2] / d[:, 2]
        t = np.where(t > 0, t, np.inf)
        ids = np.full(len(d), -1)
        for k, (lo, hi, _) in enumerate(boxes):
            t1, t2 = (lo - o) / d, (hi - o) / d
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (tn <= tf) & (tn > 0) & (tn < t)
            t = np.where(hit, tn, t)
            ids = np.where(hit, k, ids)
    ids = ids.reshape(height, width).astype(np.int32)
    depth = np.where(np.isfinite(t), np.round(t * 1000) / 1000, np.nan).astype(np.float32).reshape(height, width)
    rgb = np.zeros((height, width, 3), np.uint8)
    rgb[ids == -1] = (150, 120, 90)
    for k, (_, _, c) in enumerate(boxes):
        rgb[ids == k] = c
    return View(frame=frame, rgb=rgb, camera=cam, depth=depth, name=f"boxes {frame}"), ids
