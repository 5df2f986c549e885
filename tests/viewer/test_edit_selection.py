"""Picking in 3D without a browser (clutt3r_viewer.selection): rays, boxes of visible points, growing."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_viewer.selection import (
    ScreenCamera,
    expand_to_supervoxels,
    grow,
    pick_along_ray,
    supervoxel_adjacency,
    visible_in_rect,
)


def plane(z: float, half: float = 0.2, step: float = 0.005) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], 1)


@pytest.fixture
def two_planes():
    front = plane(1.0, 0.1)  # a small plate in front of a big wall
    back = plane(2.0, 0.5)
    return np.concatenate([front, back]), len(front)


CAM = ScreenCamera(np.zeros(3), np.eye(3), np.radians(60), 4 / 3)  # looks down +z


@settings(max_examples=50, deadline=None)
@given(st.floats(0.05, 0.95), st.floats(0.05, 0.95), st.floats(-3, 3), st.floats(-3, 3))
def test_ray_through_a_screen_point_projects_back_to_it(u, v, yaw, pitch):
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    R = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]]) @ np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    cam = ScreenCamera(np.array([0.3, -0.2, 0.5]), R, np.radians(50), 1.5)
    o, d = cam.ray(u, v)
    uu, vv, z = cam.project((o + 2.0 * d)[None])
    assert np.allclose([uu[0], vv[0]], [u, v], atol=1e-9) and z[0] > 0


def test_click_picks_the_front_surface_and_hidden_points_neither_pick_nor_block(two_planes):
    pts, nf = two_planes
    o, d = CAM.ray(0.5, 0.5)
    i = pick_along_ray(pts, o, d)
    assert 0 <= i < nf and abs(pts[i, 2] - 1.0) < 1e-9 and np.linalg.norm(pts[i, :2]) < 0.006
    cand = np.arange(len(pts)) >= nf  # the plate hidden
    j = pick_along_ray(pts, o, d, candidates=cand)
    assert j >= nf and abs(pts[j, 2] - 2.0) < 1e-9
    o2, d2 = CAM.ray(0.02, 0.02)  # a corner: nothing there
    assert pick_along_ray(pts[:nf], o2, d2) == -1


def test_box_selects_only_visible_points(two_planes):
    pts, nf = two_planes
    sel = visible_in_rect(pts, CAM, (0.2, 0.2), (0.8, 0.8))
    u, v, z = CAM.project(pts)
    inside = (u >= 0.2) & (u <= 0.8) & (v >= 0.2) & (v <= 0.8)
    # every plate point inside the box; wall points only where the plate does not cover them
    assert sel[:nf][inside[:nf]].all()
    behind_plate = (np.abs(pts[nf:, 0]) < 0.045) & (np.abs(pts[nf:, 1]) < 0.045)  # well inside its shadow
    assert not sel[nf:][behind_plate].any()
    assert sel[nf:].sum() > 0.5 * (inside[nf:] & ~behind_plate).sum()  # the visible wall is taken
    assert not sel[~inside].any()
    # the plate hidden: the wall behind it becomes selectable
    cand = np.arange(len(pts)) >= nf
    sel2 = visible_in_rect(pts, CAM, (0.2, 0.2), (0.8, 0.8), candidates=cand)
    assert sel2[nf:][behind_plate].all() and not sel2[:nf].any()


def test_grow_adds_touching_supervoxels_only():
    line = np.stack([np.arange(0, 0.1, 0.005), np.zeros(20), np.zeros(20)], 1)  # 20 points in a row
    far = line + [0, 1.0, 0]
    pts = np.concatenate([line, far])
    sv = np.concatenate([np.repeat([0, 1, 2, 3], 5), np.repeat([4], 20)])
    adj = supervoxel_adjacency(pts, sv)
    assert {tuple(e) for e in adj.tolist()} == {(0, 1), (1, 2), (2, 3)}
    m = np.zeros(len(pts), bool)
    m[7] = True  # one point of super-voxel 1
    assert np.array_equal(expand_to_supervoxels(m, sv), np.isin(sv, [1]))
    g = grow(m, sv, adj)
    assert np.array_equal(g, np.isin(sv, [0, 1, 2]))
    assert np.array_equal(grow(g, sv, adj), np.isin(sv, [0, 1, 2, 3]))
    cand = sv != 2
    assert np.array_equal(grow(m, sv, adj, cand), np.isin(sv, [0, 1]))
