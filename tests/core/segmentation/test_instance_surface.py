"""Per-instance surface step after the labelling (segmentation/instance_surface.py)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.instance_surface import InstanceSurfaceConfig, smooth_instances

VS = 0.005


def grid_surface(z_of_xy, lo=-0.03, hi=0.03, step=0.004, noise=0.0, seed=0):
    """Points on z = z_of_xy(x, y) on a grid, with gaussian noise along z (metres)."""
    g = np.arange(lo, hi + 1e-9, step)
    x, y = np.meshgrid(g, g)
    x, y = x.ravel(), y.ravel()
    z = z_of_xy(x, y) + np.random.default_rng(seed).normal(0.0, noise, len(x))
    return np.stack([x, y, z], 1)


def test_off_is_the_identity_and_config_checks():
    p = grid_surface(lambda x, y: 0 * x, noise=0.001)
    inst = np.zeros(len(p), int)
    out = smooth_instances(p, inst, InstanceSurfaceConfig())  # radius 0: off (the default)
    assert np.array_equal(out.points, p.astype(np.float32)) and not out.moved.any()
    with pytest.raises(SceneError, match="min_neighbours"):
        InstanceSurfaceConfig(radius=0.01, k=10, min_neighbours=12)
    with pytest.raises(SceneError, match="radius"):
        InstanceSurfaceConfig(radius=-0.01)
    with pytest.raises(SceneError, match="counts"):
        smooth_instances(p, inst, InstanceSurfaceConfig(radius=0.01), counts=np.ones(3))
    from clutt3r_core.config import PRESETS

    assert not PRESETS["default"].instance_surface.enabled and not PRESETS["paper"].instance_surface.enabled


def test_noise_on_a_curved_surface_is_reduced_without_the_curvature_bias():
    """A sphere cap of radius 3 cm with 1 mm noise: the projections lie closer to the sphere, and
    their mean signed error stays near 0 (a plane fit over 10 mm would sit ~0.8 mm inside)."""
    R = 0.03

    def cap(x, y):
        return np.sqrt(R * R - x * x - y * y) - R

    p = grid_surface(cap, lo=-0.015, hi=0.015, step=0.002, noise=0.001, seed=3)
    inst = np.zeros(len(p), int)
    out = smooth_instances(p, inst, InstanceSurfaceConfig(radius=0.01, max_move=0.01, keep_in_voxel=False))

    def signed(q):
        return np.linalg.norm(q - np.array([0, 0, -R]), axis=1) - R

    inner = np.abs(p[:, 0]).clip(0) ** 2 + p[:, 1] ** 2 < 0.008 ** 2  # away from the cap's border
    before, after = signed(p)[inner], signed(out.points.astype(np.float64))[inner]
    assert np.abs(after).mean() < 0.6 * np.abs(before).mean()
    assert abs(after.mean()) < 0.0003


def test_instances_are_never_averaged_across_a_contact():
    """Two instances on parallel planes 3 mm apart (an object on the table): each is smoothed with
    its own points only, so each stays on its own plane; one instance's result does not depend on
    the other's points, and unlabelled points never move."""
    a = grid_surface(lambda x, y: 0 * x, noise=0.0005, seed=1)
    b = grid_surface(lambda x, y: 0 * x + 0.003, noise=0.0005, seed=2)
    t = grid_surface(lambda x, y: 0 * x - 0.003, noise=0.0005, seed=4)
    p = np.concatenate([a, b, t])
    inst = np.r_[np.zeros(len(a), int), np.ones(len(b), int), -np.ones(len(t), int)]
    cfg = InstanceSurfaceConfig(radius=0.01, keep_in_voxel=False)
    out = smooth_instances(p, inst, cfg).points.astype(np.float64)
    za, zb = out[inst == 0, 2], out[inst == 1, 2]
    assert abs(za.mean()) < 2e-4 and abs(zb.mean() - 0.003) < 2e-4
    assert za.std() < 0.7 * a[:, 2].std() and zb.std() < 0.7 * b[:, 2].std()
    assert np.array_equal(out[inst == -1], p[inst == -1].astype(np.float32).astype(np.float64))
    alone = smooth_instances(a, np.zeros(len(a), int), cfg).points
    assert np.allclose(alone, out[inst == 0], atol=1e-7)


def test_a_point_stays_in_its_voxel_where_the_surface_crosses_it():
    """keep_in_voxel: with a fitted plane that crosses every voxel of its points, no point leaves
    its 5 mm voxel (the fusion's invariant: a voxel's point is the mean of the raw points in it)."""
    p = grid_surface(lambda x, y: 0.3 * x + 0.0011, noise=0.0008, seed=5)
    inst = np.zeros(len(p), int)
    out = smooth_instances(p, inst, InstanceSurfaceConfig(radius=0.01), voxel_size=VS)
    assert out.moved.mean() > 0.8
    crossed = np.abs(p[:, 2] - (0.3 * p[:, 0] + 0.0011)) < 0.0005  # the true plane is near the point
    v0 = np.floor(p / VS).astype(int)
    v1 = np.floor(out.points.astype(np.float64) / VS).astype(int)
    assert (v0 == v1).all(1)[crossed].mean() > 0.95
    # and the points are closer to the true plane than before
    err = lambda q: np.abs(q[:, 2] - (0.3 * q[:, 0] + 0.0011))  # noqa: E731
    assert err(out.points.astype(np.float64)).mean() < err(p).mean()


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.integers(10, 200), st.floats(0.004, 0.02), st.floats(0.0005, 0.005),
       st.booleans())
def test_properties(seed, n, radius, max_move, in_voxel):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.02, 0.02, (n, 3))
    p[:, 2] *= 0.1  # a noisy slab: a surface with noise
    inst = rng.integers(-1, 3, n)
    cfg = InstanceSurfaceConfig(radius=radius, max_move=max_move, keep_in_voxel=in_voxel)
    out = smooth_instances(p, inst, cfg, counts=rng.integers(1, 9, n), voxel_size=VS)
    assert out.points.shape == (n, 3) and np.isfinite(out.points).all()
    assert (out.shift <= max_move + 1e-6).all()  # float32 rounding of the output
    assert not out.moved[inst < 0].any()  # unlabelled points stay
    # instance ids are names: renaming them (keeping -1) moves nothing differently
    ren = np.where(inst >= 0, 7 - inst, -1)
    out2 = smooth_instances(p, ren, cfg, counts=np.ones(n), voxel_size=VS)
    out3 = smooth_instances(p, inst, cfg, counts=np.ones(n), voxel_size=VS)
    assert np.allclose(out2.points, out3.points, atol=1e-7)


def test_pipeline_hook_moves_only_labelled_points():
    """A tiny generated scene with RealSense-like depth: with the step on, the segmentation has the
    same labels, and only labelled points moved, by at most max_move."""
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from clutt3r_core.synth import SynthConfig, generate_scene

    scene = generate_scene(SynthConfig(seed=1, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    off = segment(scene, SegmentConfig())
    on = segment(scene, with_fields(SegmentConfig(), {"instance_surface.radius": 0.01}))
    assert np.array_equal(off.instance, on.instance) and np.array_equal(off.scores, on.scores)
    d = np.linalg.norm(on.points.astype(np.float64) - off.points, axis=1)
    assert (d[off.instance < 0] == 0).all()
    assert (d > 0)[off.instance >= 0].mean() > 0.5 and d.max() <= 0.004 + 1e-6
    assert any(t.stage == "instance_surface" for t in on.trace.timings)


def test_a_stored_config_without_the_stage_loads_with_it_off():
    from clutt3r_core.config import SegmentConfig, config_from_json, config_to_json

    d = config_to_json(SegmentConfig())
    d.pop("instance_surface")
    assert not config_from_json(d, "run.json").instance_surface.enabled
