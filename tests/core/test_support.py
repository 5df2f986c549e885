"""Tests of clutt3r_core/support.py: the dominant-plane RANSAC (support marking itself is
tested through the super-voxels in test_supervoxels.py, where it runs)."""
from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.support import fit_plane_ransac


def test_ransac_finds_the_dominant_plane():
    rng = np.random.default_rng(0)
    plane_pts = np.column_stack([rng.uniform(-1, 1, (3000, 2)), rng.normal(0.3, 0.002, 3000)])
    clutter = rng.uniform(-1, 1, (1000, 3))
    plane, inl = fit_plane_ransac(np.vstack([plane_pts, clutter]), 0.01)
    assert abs(abs(plane[2]) - 1) < 1e-3 and abs(abs(plane[3]) - 0.3) < 2e-3
    assert inl[:3000].mean() > 0.99 and inl[3000:].mean() < 0.05
    assert fit_plane_ransac(np.zeros((2, 3)), 0.01) is None


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), tilt=st.floats(0.0, 1.2), offset=st.floats(-0.5, 0.5),
       clutter_share=st.floats(0.0, 0.4))
def test_ransac_recovers_any_tilted_plane_under_clutter(seed, tilt, offset, clutter_share):
    # Invariant: whatever the plane's orientation and offset, a plane holding the majority of
    # the points is found (normal within 1 deg, offset within 2 mm; points are within 1 m).
    rng = np.random.default_rng(seed)
    n = np.array([np.sin(tilt), 0.0, np.cos(tilt)])
    u = np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    v = np.array([0.0, 1.0, 0.0])
    m = 2000
    k = int(m * clutter_share)
    uv = rng.uniform(-0.5, 0.5, (m, 2))
    on = uv[:, :1] * u + uv[:, 1:] * v - offset * n + rng.normal(0, 0.001, (m, 1)) * n
    pts = np.vstack([on, rng.uniform(-1, 1, (k, 3))])
    res = fit_plane_ransac(pts, 0.005)
    assert res is not None
    plane, inl = res
    assert abs(np.linalg.norm(plane[:3]) - 1) < 1e-9
    s = np.sign(plane[:3] @ n)
    assert s * plane[:3] @ n > np.cos(np.deg2rad(1.0))
    assert abs(s * plane[3] - offset) < 2e-3
    assert inl[:m].mean() > 0.95


def test_normals_gate_rejects_points_whose_normal_disagrees():
    # a horizontal plane whose every other point carries a vertical-wall normal: with the
    # gate at 0.9 those points are not inliers although they lie on the plane
    rng = np.random.default_rng(1)
    pts = np.column_stack([rng.uniform(-1, 1, (2000, 2)), np.zeros(2000)])
    normals = np.tile([0.0, 0.0, 1.0], (2000, 1))
    normals[1::2] = (1.0, 0.0, 0.0)
    plane, inl = fit_plane_ransac(pts, 0.01, normals=normals, min_normal_dot=0.9)
    assert abs(abs(plane[2]) - 1) < 1e-6
    assert inl[0::2].all() and not inl[1::2].any()
