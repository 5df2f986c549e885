"""clutt3r_viewer.app helpers that need no browser."""

from __future__ import annotations

import numpy as np

from clutt3r_viewer.camera import default_camera
from clutt3r_viewer.panels.grasps import gripper_segments
from clutt3r_viewer.panels.tree import node_kind, tree_button_label
from clutt3r_viewer.panels.tree import tree_order as _tree_order
from clutt3r_viewer.panels.views import overlay_image


def test_tree_order_lists_every_node_once_parents_first(tiny_data):
    n = tiny_data.trace.nodes
    for vi in range(len(tiny_data.trace.frames)):
        order = _tree_order(tiny_data, vi)
        nodes = [i for i, _ in order]
        assert sorted(nodes) == sorted(tiny_data.view_nodes(vi).tolist())
        pos = {i: k for k, i in enumerate(nodes)}
        depth = dict(order)
        for i in nodes:
            p = int(n.parent[i])
            if p >= 0:
                assert pos[p] < pos[i] and depth[i] == depth[p] + 1
            else:
                assert depth[i] == 0


def test_node_roles_and_labels(tiny_data):
    d = tiny_data
    kinds = {node_kind(d, i) for i in range(len(d.trace.nodes))}
    assert kinds <= {"background", "substituted", "replaced", "residual", "leaf", "parent"}
    assert "leaf" in kinds
    i = int(d.view_nodes(0)[0])
    assert f"M{int(d.trace.nodes.mask_id[i])}" in tree_button_label(d, i, 2)
    assert tree_button_label(d, i, 2).startswith("\u2003\u2003└ ")


def test_overlay_highlights_the_selected_mask(tiny_data):
    d = tiny_data
    i = int(next(j for j in d.view_nodes(0) if d.trace.nodes.is_leaf[j]))
    plain = overlay_image(d, 0)
    sel = overlay_image(d, 0, i)
    v = d.views[0]
    assert plain.shape == v.rgb.shape and plain.dtype == np.uint8  # 320 px wide: no downscale
    m = d.node_mask(i)
    diff = np.abs(sel.astype(int) - plain.astype(int)).sum(-1) > 0
    assert diff[m].mean() > 0.9  # the selected mask changed
    yellowish = (sel[..., 0] > sel[..., 2] + 40) & (sel[..., 1] > sel[..., 2] + 40)
    assert yellowish[m].mean() > yellowish[~m].mean()
    small = overlay_image(d, 0, i, max_width=100)
    assert small.shape[1] <= 100


def test_default_camera_looks_at_the_objects_from_above(tiny_data):
    cam = default_camera(tiny_data)
    look, eye = cam.look_at, cam.position
    assert eye[2] > look[2]
    assert 0.1 < np.linalg.norm(eye - look) < 10


def test_gripper_segments_follow_the_pose():
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    s = gripper_segments(T, 0.08)
    assert s.shape == (4, 2, 3)
    assert np.isclose(np.linalg.norm(s[0, 0] - s[0, 1]), 0.08)
    assert np.allclose(s[1, 1], [1 - 0.04, 2, 3.02])  # a fingertip (docs/conventions.md, "Gripper")
