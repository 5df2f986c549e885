"""A table (z = 0) with axis-aligned boxes, ray-cast exactly into posed views, fused into the
request a grasp planner gets, plus the true geometry for the evaluator (no files, no randomness)."""

from __future__ import annotations

import functools

import numpy as np

from clutt3r_core.grasping import DepthView, GraspRequest
from clutt3r_core.grasping.evaluate import SceneGeometry
from clutt3r_core.pointcloud import fuse_views
from clutt3r_core.scene import Camera, View
from tests.core._geometry_scenes import look_at

TABLE_HALF = 0.4
EYES = ((0.45, 0.0, 0.5), (-0.25, 0.4, 0.5), (-0.25, -0.4, 0.55), (0.0, 0.05, 0.6))


def render(cam: Camera, boxes: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) float32, NaN off the table; id (H, W): -1 none, 0 table, 1 + i box i)."""
    vs, us = np.mgrid[0 : cam.height, 0 : cam.width]
    dirs = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones_like(us, float)], -1).reshape(-1, 3)
    R, o = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    d = dirs @ R.T  # t along d is the z-depth (d has unit camera z)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_tab = -o[2] / d[:, 2]
        hit = o + t_tab[:, None] * d
        on = (t_tab > 0) & (np.abs(hit[:, 0]) <= TABLE_HALF) & (np.abs(hit[:, 1]) <= TABLE_HALF)
        t = np.where(on, t_tab, np.inf)
        ids = np.where(on, 0, -1)
        for i, (lo, hi) in enumerate(boxes):
            t1, t2 = (lo - o) / d, (hi - o) / d
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            bh = (tn <= tf) & (tn > 0) & (tn < t)
            t = np.where(bh, tn, t)
            ids = np.where(bh, i + 1, ids)
    depth = np.where(np.isfinite(t), t, np.nan).astype(np.float32)
    return depth.reshape(cam.height, cam.width), ids.reshape(cam.height, cam.width)


def box_mesh(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    import trimesh

    m = trimesh.creation.box(extents=np.asarray(hi) - np.asarray(lo))
    m.apply_translation((np.asarray(hi) + np.asarray(lo)) / 2)
    return np.asarray(m.vertices), np.asarray(m.faces, np.int64)


@functools.lru_cache(maxsize=8)
def box_scene(boxes: tuple[tuple[tuple[float, ...], tuple[float, ...]], ...] = (((-0.02, -0.03, 0.0), (0.02, 0.03, 0.07)),),
              n_views: int = 4, width: int = 320, height: int = 240, f: float = 400.0):
    """(request builder, geometry): ``request(target_box)`` gives the GraspRequest for box i."""
    bx = [(np.asarray(lo, float), np.asarray(hi, float)) for lo, hi in boxes]
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1]])
    views, dviews = [], []
    for i, eye in enumerate(EYES[:n_views]):
        cam = Camera(K, width, height, look_at(eye, (0.0, 0.0, 0.03)))
        depth, _ = render(cam, bx)
        views.append(View(frame=i, rgb=np.zeros((height, width, 3), np.uint8), camera=cam, depth=depth))
        dviews.append(DepthView(cam, depth))
    cloud = fuse_views(views)
    geom = SceneGeometry(tuple(box_mesh(lo, hi) for lo, hi in bx), (), 0.0)
    return cloud, tuple(dviews), bx, geom


def box_request(i: int = 0, views: bool = True, **kw) -> GraspRequest:
    cloud, dviews, bx, _ = box_scene(**kw)
    lo, hi = bx[i]
    p = cloud.points
    tgt = np.all((p >= lo - 0.003) & (p <= hi + 0.003), axis=1) & (p[:, 2] > 0.003)
    return GraspRequest(cloud.points, cloud.normals, tgt, instance=i, views=dviews if views else ())
