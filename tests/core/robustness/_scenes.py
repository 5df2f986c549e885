"""Tiny analytic tabletop scenes for the robustness tests: a table plane z = 0 with any number
of axis-aligned boxes, ray-cast exactly into posed pinhole views (no files, no randomness).

The masks of a view are one per visible box (ids 1..k in box order), then the table
(id k + 1), so a correct segmentation finds exactly the boxes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from clutt3r_core.scene import Camera, MaskCandidates, Scene, View
from tests.core._geometry_scenes import TABLE_HALF, look_at

# two well separated boxes (metres): 10 x 10 x 8 cm and 8 x 6 x 12 cm
BOXES: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
    ((-0.12, -0.05, 0.0), (-0.02, 0.05, 0.08)),
    ((0.04, -0.03, 0.0), (0.12, 0.03, 0.12)),
)
EYES = ((0.40, 0.0, 0.45), (-0.20, 0.35, 0.45), (-0.20, -0.35, 0.50), (0.0, 0.40, 0.55))
COLOURS = ((200, 30, 30), (30, 160, 40), (40, 60, 200), (200, 200, 40))


def render(cam: Camera, boxes, table_half: float = TABLE_HALF) -> tuple[np.ndarray, np.ndarray]:
    """(depth (H, W) float32, NaN off the table; id (H, W) int32: -1 none, 0 table, k + 1 box k)."""
    vs, us = np.mgrid[0 : cam.height, 0 : cam.width]
    d = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones(us.shape)], -1).reshape(-1, 3)
    R, o = cam.T_world_camera[:3, :3], cam.T_world_camera[:3, 3]
    d = d @ R.T  # unit camera z: the ray parameter is the z-depth
    with np.errstate(divide="ignore", invalid="ignore"):
        t_tab = -o[2] / d[:, 2]
        hit = o + t_tab[:, None] * d
        on = (t_tab > 0) & (np.abs(hit[:, 0]) <= table_half) & (np.abs(hit[:, 1]) <= table_half)
        t = np.where(on, t_tab, np.inf)
        ids = np.where(on, 0, -1)
        for k, (lo, hi) in enumerate(boxes):
            t1, t2 = (np.asarray(lo) - o) / d, (np.asarray(hi) - o) / d
            tn = np.nanmax(np.minimum(t1, t2), axis=1)
            tf = np.nanmin(np.maximum(t1, t2), axis=1)
            h = (tn <= tf) & (tn > 0) & (tn < t)
            t, ids = np.where(h, tn, t), np.where(h, k + 1, ids)
    depth = np.where(np.isfinite(t), t, np.nan).astype(np.float32).reshape(cam.height, cam.width)
    return depth, ids.reshape(cam.height, cam.width).astype(np.int32)


def make_view(frame: int, eye, boxes=BOXES, width: int = 160, height: int = 120, f: float = 170.0,
              target=(0.0, 0.0, 0.03), table_half: float = TABLE_HALF) -> View:
    K = np.array([[f * width / 160, 0, (width - 1) / 2], [0, f * width / 160, (height - 1) / 2], [0, 0, 1]])
    cam = Camera(K, width, height, look_at(eye, target))
    depth, ids = render(cam, boxes, table_half)
    rgb = np.full((height, width, 3), 20, np.uint8)
    rgb[ids == 0] = (190, 190, 190)
    masks = []
    for k in range(len(boxes)):
        rgb[ids == k + 1] = COLOURS[k % len(COLOURS)]
        masks.append(ids == k + 1)
    masks.append(ids == 0)
    stack = np.stack(masks)
    return View(frame=frame, rgb=rgb, camera=cam, depth=depth,
                masks=MaskCandidates(stack, np.arange(1, len(stack) + 1, dtype=np.int32)),
                name=f"image_{frame:06d}.png")


def make_scene(n_views: int = 3, boxes=BOXES, frames=None, **kw) -> Scene:
    frames = list(range(n_views)) if frames is None else list(frames)
    views = tuple(make_view(fr, EYES[i % len(EYES)], boxes, **kw) for i, fr in enumerate(frames))
    return Scene(views=views, initial=tuple(range(len(views))), name="robust")


def with_masks(view: View, masks: np.ndarray, ids=None) -> View:
    ids = np.arange(1, len(masks) + 1, dtype=np.int32) if ids is None else np.asarray(ids, np.int32)
    return replace(view, masks=MaskCandidates(np.asarray(masks, bool), ids))


def box_of_points(points: np.ndarray, boxes=BOXES, margin: float = 0.006) -> np.ndarray:
    """(N,) int: the box each point lies in (within ``margin`` metres, about one voxel), -1 none."""
    out = np.full(len(points), -1)
    for k, (lo, hi) in enumerate(boxes):
        inside = np.all((points >= np.asarray(lo) - margin) & (points <= np.asarray(hi) + margin), axis=1)
        inside &= points[:, 2] > 0.01  # the table top under a box is not the box
        out[inside & (out < 0)] = k
    return out


def assert_boxes_found(seg, boxes=BOXES, min_purity: float = 0.9, min_recall: float = 0.5) -> None:
    """Exactly one instance per box: each instance's points lie mostly in one box, each box is
    mostly covered by one instance."""
    truth = box_of_points(seg.points, boxes)
    assert seg.num_instances == len(boxes), f"{seg.num_instances} instances for {len(boxes)} boxes"
    matched = set()
    for k in range(seg.num_instances):
        sel = seg.instance == k
        lab, cnt = np.unique(truth[sel], return_counts=True)
        best = lab[np.argmax(cnt)]
        purity = cnt.max() / sel.sum()
        assert best >= 0 and purity >= min_purity, f"instance {k}: box {best}, purity {purity:.2f}"
        recall = np.count_nonzero(sel & (truth == best)) / np.count_nonzero(truth == best)
        assert recall >= min_recall, f"instance {k}: recall of box {best} {recall:.2f}"
        matched.add(int(best))
    assert matched == set(range(len(boxes)))
