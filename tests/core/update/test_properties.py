"""Property tests of the update's building blocks: the z-buffer and the state transition."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.update import InstanceUpdate, UpdateResult
from clutt3r_core.update.project import splat
from clutt3r_core.update.state import SceneState, apply_update

from ._scenes import camera, yaw_motion


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 60))
def test_zbuffer_keeps_the_nearest_splat(seed, n):
    rng = np.random.default_rng(seed)
    cam = camera(width=40, height=30, f=40.0)
    pts = rng.uniform([-0.1, -0.1, 0.0], [0.1, 0.1, 0.1], (n, 3))
    s = splat(pts, cam, voxel=0.01)
    # brute force: every point's square footprint, nearest z per pixel
    uv, z = cam.project(pts)
    ref = np.full((cam.height, cam.width), np.inf)
    for (u, v), zz, r in zip(np.round(uv).astype(int), z, s.radius):
        if not zz > 0:
            continue
        v0, v1, u0, u1 = max(v - r, 0), min(v + r + 1, cam.height), max(u - r, 0), min(u + r + 1, cam.width)
        if v0 < v1 and u0 < u1:
            ref[v0:v1, u0:u1] = np.minimum(ref[v0:v1, u0:u1], zz)
    full = np.full((cam.height, cam.width), np.inf)
    full[s.v0 : s.v0 + s.h, s.u0 : s.u0 + s.w] = s.zbuf
    np.testing.assert_allclose(full, ref)
    hit = s.point >= 0
    np.testing.assert_allclose(z[s.point[hit]], s.zbuf[hit])  # the winning point is the nearest


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(1, 80), scale=st.floats(0.5, 4.0))
def test_zbuffer_by_minimum_filters_equals_the_per_offset_zbuffer(seed, n, scale):
    # with_points=False (the pose fit's fast path) must give the same z-buffer, window and
    # centres, also for points centred outside the image whose splats reach into it
    rng = np.random.default_rng(seed)
    cam = camera(width=40, height=30, f=40.0)
    pts = rng.uniform([-0.2, -0.2, 0.0], [0.2, 0.2, 0.15], (n, 3))
    a = splat(pts, cam, voxel=0.01, scale=scale)
    b = splat(pts, cam, voxel=0.01, scale=scale, with_points=False)
    assert (a.v0, a.u0, a.h, a.w) == (b.v0, b.u0, b.h, b.w)
    np.testing.assert_array_equal(a.zbuf, b.zbuf)
    np.testing.assert_array_equal(a.centre, b.centre)
    assert np.all(b.point == -1)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), k=st.integers(2, 6), yaw=st.floats(-180, 180), shift=st.floats(-0.1, 0.1))
def test_apply_update_moves_rigidly_and_drops_removed(seed, k, yaw, shift):
    rng = np.random.default_rng(seed)
    n = 50 * k
    inst = rng.integers(0, k, n).astype(np.int32)
    inst[:k] = np.arange(k)  # every id present
    pts = rng.normal(size=(n, 3)).astype(np.float32)
    state = SceneState(pts, rng.integers(0, 255, (n, 3)).astype(np.uint8), inst, np.arange(k, dtype=np.int32),
                       np.eye(k, 4, dtype=np.float32), "appearance-hsv")
    T = yaw_motion(yaw, (shift, -shift, 0.0), pts[inst == 0].mean(axis=0))
    recs = [InstanceUpdate(0, "displaced", 0.1, 0.9, T), InstanceUpdate(1, "removed", None, None, None)]
    recs += [InstanceUpdate(i, "static", 0.9, 0.9, None) for i in range(2, k)]
    res = UpdateResult(3, tuple(recs), (), np.zeros((k, 2, 2), bool), np.full((2, 2), -1, np.int32), 0.0)
    nxt = apply_update(state, res)
    assert 1 not in nxt.instance_ids and not np.any(nxt.instance == 1)
    assert len(nxt.points) == int(np.sum(inst != 1))
    a, b = state.points_of(0).astype(np.float64), nxt.points_of(0).astype(np.float64)
    np.testing.assert_allclose(b, a @ T[:3, :3].T + T[:3, 3], atol=1e-5)
    for i in range(2, k):
        np.testing.assert_array_equal(nxt.points_of(i), state.points_of(i))
    np.testing.assert_array_equal(nxt.embeddings, state.embeddings[[i for i in range(k) if i != 1]])
    assert nxt.step == 1 and nxt.history[0].removed == (1,) and nxt.history[0].displaced == (0,)
