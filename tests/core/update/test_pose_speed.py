"""The pose fit's speed-ups change no bit of its result: the hand-written Adam against torch's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

torch = pytest.importorskip("torch")

from clutt3r_core.update.pose import _Adam  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40))
def test_adam_bit_identical_to_torch(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    w0, t0 = rng.normal(size=3), rng.normal(size=3)
    ws = [torch.tensor(w0, requires_grad=True) for _ in range(2)]
    ts = [torch.tensor(t0, requires_grad=True) for _ in range(2)]
    ref = torch.optim.Adam([{"params": [ws[0]], "lr": 0.05}, {"params": [ts[0]], "lr": 0.01}])
    ours = _Adam(torch, [{"params": [ws[1]], "lr": 0.05}, {"params": [ts[1]], "lr": 0.01}])
    for i in range(n):
        f = 0.1 ** (i / max(n - 1, 1))  # the schedule's decay: lr changes every step
        scale = 10.0 ** rng.uniform(-6, 2)
        gw, gt = rng.normal(size=3) * scale, rng.normal(size=3) * scale
        for opt, w, t in ((ref, ws[0], ts[0]), (ours, ws[1], ts[1])):
            for g, lr in zip(opt.param_groups, (0.05, 0.01)):
                g["lr"] = lr * f
            opt.zero_grad()
            assert w.grad is None and t.grad is None
            loss = (w * torch.tensor(gw)).sum() + (t * torch.tensor(gt)).sum()
            loss.backward()
            opt.step()
        assert torch.equal(ws[0], ws[1]) and torch.equal(ts[0], ts[1])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
       density=st.floats(0.0, 0.5), grow=st.integers(0, 5))
def test_near_outside_matches_distance_transform(seed: int, h: int, w: int, density: float, grow: int) -> None:
    """The contour test of the loss: the same booleans as the former full distance transform."""
    from scipy import ndimage

    from clutt3r_core.update.pose import _near_outside

    rng = np.random.default_rng(seed)
    sil = rng.random((h, w)) < density
    if grow:
        sil = ndimage.binary_dilation(sil, iterations=grow)
    flat = rng.integers(0, h * w, 80)
    reach = rng.integers(0, 13, 80) + 1.5  # splat radii 0..12 (project._MAX_RADIUS) + 1.5
    ref = ndimage.distance_transform_edt(np.pad(sil, 1))[1:-1, 1:-1].reshape(-1)[flat] <= reach
    assert np.array_equal(_near_outside(sil, flat, reach), ref)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 60), w=st.integers(1, 60), r=st.integers(0, 12),
       fill=st.floats(0.0, 1.0))
def test_zbuf_filter_matches_scipy_minimum_filter(seed: int, h: int, w: int, r: int, fill: float) -> None:
    """project._zbuf_by_filter's OpenCV erosion: scipy's constant-inf minimum filter, bit for bit."""
    import cv2
    from scipy.ndimage import minimum_filter

    rng = np.random.default_rng(seed)
    a = np.where(rng.random((h, w)) < fill, rng.uniform(0.05, 5.0, (h, w)), np.inf)
    ref = minimum_filter(a, size=2 * r + 1, mode="constant", cval=np.inf)
    out = cv2.erode(a, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                    borderValue=np.inf)
    assert out.dtype == np.float64 and np.array_equal(out, ref)


def _splat_points_reference(points, camera, voxel, scale=1.0, window=None):
    """project.splat's point buffer as written before the winner pre-selection (every point
    expanded to every offset, ``np.minimum.at``): the reference the fast path must equal."""
    from clutt3r_core.update.project import splat_inputs

    # the projection, radii and window are splat's own (shared); the buffer writing below is the old one
    z, u, v, r, ok, (v0, u0, h, w) = splat_inputs(points, camera, voxel, scale, window)
    zbuf, pbuf = np.full(h * w, np.inf), np.full(h * w, -1, np.int64)
    idx = np.flatnonzero(ok)
    rmax = int(r[idx].max())
    d = np.arange(-rmax, rmax + 1)
    dv, du = (a.ravel() for a in np.meshgrid(d, d, indexing="ij"))
    reach = np.maximum(np.abs(du), np.abs(dv))
    uu, vv = u[idx, None] + du[None, :] - u0, v[idx, None] + dv[None, :] - v0
    sel = (r[idx, None] >= reach[None, :]) & (uu >= 0) & (uu < w) & (vv >= 0) & (vv < h)
    flat = (vv * w + uu)[sel]
    zz = np.broadcast_to(z[idx, None], sel.shape)[sel]
    pi = np.broadcast_to(idx[:, None], sel.shape)[sel]
    np.minimum.at(zbuf, flat, zz)
    win = zz == zbuf[flat]
    pbuf[flat[win]] = pi[win]
    return zbuf.reshape(h, w), pbuf.reshape(h, w)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 400), dup=st.booleans(), windowed=st.booleans())
def test_splat_point_buffer_matches_full_expansion(seed: int, n: int, dup: bool, windowed: bool) -> None:
    """The winner pre-selection of splat(with_points=True) keeps every point buffer entry, ties
    (duplicated points) and points whose splats only graze the image included."""
    from clutt3r_core.scene import Camera
    from clutt3r_core.update.project import splat

    rng = np.random.default_rng(seed)
    K = np.array([[60.0, 0, 40], [0, 60.0, 30], [0, 0, 1]])
    cam = Camera(K=K, width=80, height=60, T_world_camera=np.eye(4))
    pts = np.column_stack([rng.uniform(-0.9, 0.9, n), rng.uniform(-0.7, 0.7, n), rng.uniform(0.05, 1.5, n)])
    if dup:  # exact z ties at shared pixels
        pts = np.concatenate([pts, pts[: n // 2]])
    pts = np.round(pts, 2)  # more ties of z between different points
    window = (int(rng.integers(0, 30)), int(rng.integers(0, 40)), int(rng.integers(1, 30)), int(rng.integers(1, 40))) \
        if windowed else None
    s = splat(pts, cam, voxel=0.01, window=window)
    if not (s.h and s.w) or not np.isfinite(s.z).any():
        return
    zref, pref = _splat_points_reference(pts, cam, 0.01, window=window)
    assert np.array_equal(s.zbuf, zref)
    assert np.array_equal(s.point, pref)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 300), ties=st.booleans())
def test_zbuf_on_ranks_equals_the_zbuf_on_z(seed: int, n: int, ties: bool) -> None:
    """project._zbuf_by_filter filters float32 ranks and maps them back to z: the same float64
    z-buffer as filtering the z themselves (its path for 2^24 points or more), several radius
    groups, tied depths and points centred outside the window included."""
    from clutt3r_core.update import project

    rng = np.random.default_rng(seed)
    h, w = int(rng.integers(1, 50)), int(rng.integers(1, 50))
    u = rng.integers(-8, w + 8, n)
    v = rng.integers(-8, h + 8, n)
    r = rng.integers(0, 6, n)
    z = np.round(rng.uniform(0.2, 2.0, n), 2 if ties else 12)
    idx = np.flatnonzero(rng.random(n) < 0.9)
    if not len(idx):
        return
    ranked = project._zbuf_by_filter(z, u, v, r, idx, 0, 0, h, w)
    old, project._RANK_LIMIT = project._RANK_LIMIT, 0
    try:
        direct = project._zbuf_by_filter(z, u, v, r, idx, 0, 0, h, w)
    finally:
        project._RANK_LIMIT = old
    assert ranked.dtype == direct.dtype == np.float64 and np.array_equal(ranked, direct)


def _splat_inputs_reference(points, camera, voxel, scale):
    """project.splat_inputs' projection and radii as written before the inlined fast path:
    ``Camera.project`` and ``splat_radius`` (session 6 must equal them bit for bit)."""
    from clutt3r_core.update.project import splat_radius

    uv, z = camera.project(points)
    ok = np.isfinite(z) & (z > 1e-6) & np.all(np.isfinite(uv), axis=1)
    u = np.round(np.where(ok, uv[:, 0], 0)).astype(np.int64)
    v = np.round(np.where(ok, uv[:, 1], 0)).astype(np.int64)
    r = splat_radius(np.where(ok, z, np.inf), camera, voxel, scale)
    ok &= (u + r >= 0) & (u - r < camera.width) & (v + r >= 0) & (v - r < camera.height)
    return z, u, v, r, ok


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 300), scale=st.sampled_from([1.0, 1.7, 3.0]),
       near=st.booleans())
def test_splat_inputs_equal_camera_project_and_splat_radius(seed: int, n: int, scale: float, near: bool) -> None:
    """The inlined projection and radii of splat_inputs: the same z, u, v, r and ``ok`` as
    Camera.project + splat_radius, points behind the camera, at z ~ 0, far outside the image
    and closer than the radius cap included; and the cached camera inverse follows the camera."""
    from clutt3r_core.scene import Camera
    from clutt3r_core.update.project import splat_inputs
    from tests.core.update._scenes import camera as make_camera

    rng = np.random.default_rng(seed)
    for cam in (make_camera(), make_camera(eye=(0.3, -0.3, 0.5)),
                Camera(K=np.array([[300.0, 0, 90], [0, 280.0, 70], [0, 0, 1]]), width=180, height=140,
                       T_world_camera=np.eye(4))):
        c = cam.T_world_camera[:3, 3]
        p = c + rng.normal(0, 0.02 if near else 0.4, (n, 3))
        p[: n // 10] = c  # z = 0 exactly (camera centre)
        got = splat_inputs(p, cam, 0.005, scale)
        ref = _splat_inputs_reference(p, cam, 0.005, scale)
        for a, b in zip(got[:5], ref):
            assert a.dtype == b.dtype and np.array_equal(a, b)


def test_zbuffer_only_splat_has_no_point_buffer() -> None:
    """with_points=False: the point buffer is all -1 (a read-only view, nothing to allocate)."""
    from clutt3r_core.update.project import splat
    from tests.core.update._scenes import camera as make_camera

    cam = make_camera()
    p = np.random.default_rng(0).normal([0, 0, 0.03], 0.02, (200, 3))
    s = splat(p, cam, 0.005, with_points=False)
    assert s.h and s.w and s.point.shape == (s.h, s.w) and (s.point == -1).all()
    assert np.array_equal(s.zbuf, splat(p, cam, 0.005).zbuf)
