"""Tiny synthetic stored scenes and their post-interaction views for the update tests.

Objects are textured boxes sampled at 5 mm on their surface (no bottom face), resting on
the table (z = 0); a view is rendered by z-buffering the points themselves (the same
splats the update uses), so a known motion gives an exact target mask and image.
"""

from __future__ import annotations

import numpy as np

from clutt3r_core.embeddings import AppearanceEmbedder
from clutt3r_core.scene import Camera, MaskCandidates, View
from clutt3r_core.update.project import render_labels
from clutt3r_core.update.state import SceneState

VOXEL = 0.005


def look_at(eye, target=(0.0, 0.0, 0.03), up=(0.0, 0.0, 1.0)) -> np.ndarray:
    eye, target, up = (np.asarray(x, float) for x in (eye, target, up))
    z = target - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = eye
    return T


def camera(eye=(0.0, -0.45, 0.4), target=(0.0, 0.0, 0.03), width=200, height=150, f=220.0) -> Camera:
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    return Camera(K, width, height, look_at(eye, target))


def box_points(center, size, colors, seed=0) -> tuple[np.ndarray, np.ndarray]:
    """Surface points (5 mm grid) of an axis-aligned box standing on z = center_z - size_z/2,
    each face its own colour (colors: (5, 3) uint8 for +x, -x, +y, -y, +z), with a dark stripe."""
    c, s = np.asarray(center, float), np.asarray(size, float)
    pts, cols = [], []
    g = lambda n: np.linspace(-0.5, 0.5, max(2, int(round(n / VOXEL)) + 1))  # noqa: E731
    faces = [(0, 1), (0, -1), (1, 1), (1, -1), (2, 1)]
    for fi, (ax, sign) in enumerate(faces):
        o = [a for a in range(3) if a != ax]
        A, B = np.meshgrid(g(s[o[0]]), g(s[o[1]]), indexing="ij")
        p = np.zeros((A.size, 3))
        p[:, ax] = 0.5 * sign
        p[:, o[0]], p[:, o[1]] = A.ravel(), B.ravel()
        pts.append(c + p * s)
        col = np.tile(np.asarray(colors[fi], np.uint8), (A.size, 1))
        stripe = np.abs(A.ravel() - 0.15) < 0.1
        col[stripe] = (col[stripe] * 0.3).astype(np.uint8)
        cols.append(col)
    return np.concatenate(pts).astype(np.float32), np.concatenate(cols)


def yaw_motion(yaw_deg: float, t, center) -> np.ndarray:
    """World motion: turn by yaw about the vertical axis through ``center``, then translate by t."""
    a = np.deg2rad(yaw_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = np.asarray(center) + np.asarray(t) - R @ np.asarray(center)
    return T


def two_box_scene():
    """Two boxes (instances 0 and 1): points, colours, instance labels."""
    p0, c0 = box_points((-0.06, 0.0, 0.03), (0.06, 0.04, 0.06),
                        [(200, 40, 40), (180, 30, 30), (220, 120, 40), (150, 20, 60), (240, 200, 60)])
    p1, c1 = box_points((0.07, 0.03, 0.025), (0.05, 0.05, 0.05),
                        [(40, 60, 200), (30, 160, 200), (40, 200, 90), (20, 90, 150), (120, 220, 240)])
    pts = np.concatenate([p0, p1])
    cols = np.concatenate([c0, c1])
    inst = np.concatenate([np.zeros(len(p0), np.int32), np.ones(len(p1), np.int32)])
    return pts, cols, inst


def render_view(points, colors, inst, cam: Camera, frame=9, with_depth=True, background=(90, 90, 90)) -> View:
    """RGB, depth and one exact mask per visible instance (ids = instance + 1)."""
    lab, z = render_labels(points, np.arange(len(points)), cam, VOXEL)
    rgb = np.tile(np.asarray(background, np.uint8), (cam.height, cam.width, 1))
    hit = lab >= 0
    rgb[hit] = colors[lab[hit]]
    ids = np.where(hit, inst[np.where(hit, lab, 0)], -1)
    present = [k for k in np.unique(ids) if k >= 0]
    masks = MaskCandidates(np.stack([ids == k for k in present]) if present else np.zeros((0, cam.height, cam.width), bool),
                           np.array([k + 1 for k in present], np.int32))
    depth = np.where(hit, z, np.nan).astype(np.float32) if with_depth else None
    return View(frame=frame, rgb=rgb, camera=cam, depth=depth, masks=masks)


def state_of(pts, cols, inst) -> SceneState:
    """The stored state of a scene: its instances (ids >= 0 of ``inst``) with the appearance
    embedding of their masks in a view from ``camera()`` (rows follow the ids)."""
    ids = np.unique(inst[inst >= 0]).astype(np.int32)
    v = render_view(pts, cols, inst, camera(), frame=0)
    emb = AppearanceEmbedder().embed_masks(v.rgb, v.masks.masks)
    by_id = {int(m) - 1: e for m, e in zip(v.masks.ids, emb)}  # render_view's mask ids are instance + 1
    return SceneState(pts, cols, inst, ids, np.stack([by_id.get(int(k), emb[0]) for k in ids]), "appearance-hsv")


def table_points(x=(-0.2, 0.2), y=(-0.12, 0.2)) -> tuple[np.ndarray, np.ndarray]:
    """A textured table top at z = 0 (5 mm grid, grey stripes 1.5 cm wide): the background
    (instance -1) that a real run's cloud holds around the objects."""
    X, Y = np.meshgrid(np.arange(x[0], x[1], VOXEL), np.arange(y[0], y[1], VOXEL), indexing="ij")
    pts = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1).astype(np.float32)
    stripe = (np.floor(X.ravel() / 0.015).astype(np.int64) % 2).astype(np.uint8)
    cols = np.stack([100 + 30 * stripe, 98 + 30 * stripe, 92 + 28 * stripe], axis=1).astype(np.uint8)
    return pts, cols


def two_boxes_on_a_table():
    """``two_box_scene`` plus ``table_points`` as background (instance -1)."""
    pts, cols, inst = two_box_scene()
    tp, tc = table_points()
    return (np.concatenate([pts, tp]), np.concatenate([cols, tc]),
            np.concatenate([inst, np.full(len(tp), -1, np.int32)]))


def noisy_contact_run(root, seed: int):
    """(run folder, its ``pipeline.Segmentation``, its labels before the contact rule) of a tiny
    generated easy scene with RealSense-like depth (``seed``, 3 views at 320 x 240, 3 objects) saved
    under ``root`` with its scene folder, segmented with the contact rule alone: the tests of the
    labels before the rule read its cleared points (the contact fill, off by default, would add
    points that are no pre-contact label; tests/core/segmentation/test_table_contact.py)."""
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from clutt3r_core.runs import save_run
    from clutt3r_core.segmentation.refine import run_labels_before_contact
    from clutt3r_core.synth import write_synth_scene
    from clutt3r_core.synth.generator import SynthConfig, generate_scene

    scene = generate_scene(SynthConfig(seed=seed, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    seg = segment(scene, with_fields(SegmentConfig(), {"refine.contact_fill_high": 0.0}))
    run = save_run(seg, root / "run", scene_root=write_synth_scene(scene, root / "scene", contact_sheet=False))
    return run, seg, run_labels_before_contact(seg)
