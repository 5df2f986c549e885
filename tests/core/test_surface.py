"""The multi-view surface estimate of the fusion (``clutt3r_core.surface``, ``PointCloudConfig.surface``)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.config import ADDITIONS, PRESETS, SegmentConfig
from clutt3r_core.errors import SceneError
from clutt3r_core.pointcloud import PointCloudConfig, fuse_views
from clutt3r_core.scene import Camera, View
from clutt3r_core.surface import SurfaceParams, smooth_depth, snap_to_surface
from tests.core._geometry_scenes import BOX_MAX, BOX_MIN, look_at, make_views

TSDF = PointCloudConfig(surface="tsdf")
PLAIN = PointCloudConfig(surface="voxel-mean")


def _noisy(views: list[View], sigma: float, seed: int = 0) -> list[View]:
    """The views with white Gaussian depth noise of ``sigma`` metres (holes stay holes)."""
    rng = np.random.default_rng(seed)
    out = []
    for v in views:
        d = v.depth + rng.normal(0.0, sigma, v.depth.shape).astype(np.float32)
        out.append(dataclasses.replace(v, depth=d))
    return out


def _table_far_from_box(points: np.ndarray) -> np.ndarray:
    """(N,) bool: points over the table at least 3 cm from the box's footprint."""
    return ((np.abs(points[:, 0]) > BOX_MAX[0] + 0.03) | (np.abs(points[:, 1]) > BOX_MAX[1] + 0.03)) & (
        np.abs(points[:, 2]) < 0.03)


def test_noisy_table_fuses_to_a_thin_surface():
    """Depth noise spreads the plain fusion over several voxels across the table; the consensus
    surface is much thinner (the off-surface cells of issue 13)."""
    views = _noisy(make_views(3, 320, 240, 400.0), 0.003)
    plain = fuse_views(views, PLAIN)
    tsdf = fuse_views(views, TSDF)
    zp = plain.points[_table_far_from_box(plain.points), 2]
    zt = tsdf.points[_table_far_from_box(tsdf.points), 2]
    rms_p, rms_t = np.sqrt(np.mean(zp**2)), np.sqrt(np.mean(zt**2))
    assert rms_t < 0.6 * rms_p, (rms_t, rms_p)
    # voxels whose mean is off the plane by more than half a voxel: the thickening
    assert np.mean(np.abs(zt) > 0.0025) < 0.5 * np.mean(np.abs(zp) > 0.0025)
    # the table is still covered: about as many 10 mm cells on the plane as the plain fusion
    cells = lambda p: len(np.unique(np.floor(p[_table_far_from_box(p)][:, :2] / 0.01).astype(int), axis=0))  # noqa: E731
    assert cells(tsdf.points) >= 0.97 * cells(plain.points)


def test_clean_depth_stays_on_the_surface():
    """Without noise the views already agree: the moved points stay on the table and the box."""
    views = make_views(3, 320, 240, 400.0)
    cloud = fuse_views(views, TSDF)
    p = cloud.points.astype(np.float64)
    # distance to the scene: the table plane z = 0 or the box surface
    inside = np.clip(p, BOX_MIN, BOX_MAX)
    d_box = np.linalg.norm(p - inside, axis=1)
    in_box = np.all((p > BOX_MIN) & (p < BOX_MAX), axis=1)
    d_box[in_box] = np.min(np.abs(np.concatenate([p[in_box] - BOX_MIN, BOX_MAX - p[in_box]], axis=1)), axis=1)
    dist = np.minimum(np.abs(p[:, 2]), d_box)
    assert np.percentile(dist, 99) < 0.0015, np.percentile(dist, [50, 99, 100])
    # nothing lost: the table and the box top cover as many 10 mm columns as in the plain fusion
    # (voxel counts differ: the plain fusion splits points at exactly z = 0 over two voxel layers)
    plain = fuse_views(views, PLAIN)
    cols = lambda c: len(np.unique(np.floor(c.points[:, :2] / 0.01).astype(int), axis=0))  # noqa: E731
    assert cols(cloud) >= 0.98 * cols(plain)


def test_pixel_maps_follow_the_moved_points():
    """A pixel maps to the voxel its moved point landed in: that voxel's mean lies within one
    voxel diagonal plus the largest move of the pixel's raw point."""
    views = _noisy(make_views(3, 160, 120, 200.0), 0.003, seed=1)
    cloud = fuse_views(views, TSDF)
    reach = cloud.voxel_size * np.sqrt(3) + SurfaceParams().max_shift
    for v, view in enumerate(views):
        pix, vox = cloud.pixel_voxel.pixels(v)
        assert len(pix) > 0.5 * np.isfinite(view.depth).sum()
        raw, raw_pix = view.camera.backproject(view.depth)
        pos = np.searchsorted(raw_pix, pix)
        assert np.all(raw_pix[pos] == pix)
        gap = np.linalg.norm(raw[pos] - cloud.points[vox].astype(np.float64), axis=1)
        assert gap.max() <= reach + 1e-6
        assert np.all(cloud.visibility[v, vox])


def test_view_order_does_not_matter():
    views = _noisy(make_views(3, 160, 120, 200.0), 0.002, seed=2)
    a = fuse_views(views, TSDF)
    b = fuse_views(views[::-1], TSDF)
    assert a.num == b.num
    np.testing.assert_allclose(a.points, b.points, atol=1e-5)
    np.testing.assert_array_equal(a.counts, b.counts)


@settings(max_examples=25, deadline=None)
@given(
    tilt=st.floats(0.0, 0.6),
    azim=st.floats(-np.pi, np.pi),
    height=st.floats(-0.05, 0.05),
    seed=st.integers(0, 2**16),
)
def test_a_clean_plane_is_a_fixed_point(tilt, azim, height, seed):
    """Noise-free depth of any plane, seen from three cameras: the points stay on it.

    Not all of them (a known limitation, docs/benchmark/strict-iou.md): where the set of views
    that see a voxel changes (the border of a view) its finite-difference gradient tilts, and a
    plane lying exactly on a voxel boundary (z = 0 for tilt 0) has voxels on both sides of it;
    measured, a few points near a view's border move up to 6 mm off the plane and the 90th
    percentile reaches 0.6 mm on steep planes; the median stays under 0.1 mm. Asserted: median
    0.1 mm, 90th percentile 1 mm (a fifth of a voxel). A counterexample hypothesis found after
    many runs (2026-12-01, present at 35e98a0 too): tilt 0.5625, azim 0.75, height 0, seed 2089
    gives a 90th percentile of 1.07 mm (max 5.4 mm); 0 of 600 random draws (300 of them at
    height 0, the voxel-boundary case) exceed 1 mm. Kept as the bound: it is the estimate's
    known border error, not a tolerance to widen."""
    n = np.array([np.sin(tilt) * np.cos(azim), np.sin(tilt) * np.sin(azim), np.cos(tilt)])
    rng = np.random.default_rng(seed)
    views = []
    for i in range(3):
        a = rng.uniform(-np.pi, np.pi)
        eye = np.array([0.3 * np.cos(a), 0.3 * np.sin(a), rng.uniform(0.35, 0.5)])
        T = look_at(eye, target=(0.0, 0.0, height))
        cam = Camera(np.array([[150.0, 0, 39.5], [0, 150.0, 29.5], [0, 0, 1]]), 80, 60, T)
        vs, us = np.mgrid[0:60, 0:80]
        rays = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones_like(us, float)], -1) @ T[:3, :3].T
        # plane n . x = height * n_z through (0, 0, height); z-depth t along rays of unit camera z
        t = (height * n[2] - eye @ n) / (rays @ n)
        depth = np.where(t > 0, t, np.nan).astype(np.float32)
        views.append(View(frame=i, rgb=np.zeros((60, 80, 3), np.uint8), camera=cam, depth=depth))
    P = np.concatenate([v.camera.backproject(v.depth)[0].astype(np.float32) for v in views])
    sn = snap_to_surface(views, P, [1, 1, 1])
    dist = np.abs((sn.points.astype(np.float64) - (0.0, 0.0, height)) @ n)
    assert sn.moved.mean() > 0.8
    assert np.median(dist) < 1e-4, np.percentile(dist, [50, 90, 100])
    assert np.percentile(dist, 90) < 1e-3, np.percentile(dist, [50, 90, 100])


def test_smooth_depth_keeps_edges_and_averages_planes():
    rng = np.random.default_rng(0)
    z = np.full((40, 40), 0.6, np.float32)
    z[:, 20:] = 0.7  # a 10 cm depth edge
    noisy = z + rng.normal(0, 0.002, z.shape).astype(np.float32)
    noisy[5, 5] = np.nan
    s = smooth_depth(noisy, 5, 0.004)
    flat = np.zeros_like(z, bool)
    flat[3:-3, 3:16] = flat[3:-3, 24:-3] = True
    flat[5, 5] = False
    assert np.std((s - z)[flat]) < 0.4 * np.std((noisy - z)[flat])
    # at the edge the raw depth is kept: nothing between the two levels
    assert not np.any((s > 0.62) & (s < 0.68))
    assert np.isnan(s[5, 5])


def test_config_switch_and_presets():
    with pytest.raises(SceneError, match="'voxel-mean', 'tsdf' or 'auto'"):
        PointCloudConfig(surface="mls")  # type: ignore[arg-type]
    with pytest.raises(SceneError):
        SurfaceParams(truncation=0.0)
    with pytest.raises(SceneError):
        PointCloudConfig(surface_min_points=0)
    # ours runs it when the depth is noisy ("auto"), the paper never: listed in ADDITIONS
    assert PRESETS["paper"].pointcloud.surface == "voxel-mean"
    assert SegmentConfig().pointcloud.surface == "auto"
    in_additions = any(f == "pointcloud.surface" for a in ADDITIONS for f, _, _ in a.fields)
    assert in_additions == (SegmentConfig().pointcloud.surface != "voxel-mean")


def test_views_without_any_depth_give_an_empty_cloud():
    """As the plain fusion: no raw point, no voxel (the pipeline's depth check then names the views)."""
    views = [dataclasses.replace(v, depth=np.full_like(v.depth, np.nan)) for v in make_views(2)]
    assert fuse_views(views, TSDF).num == 0 == fuse_views(views, PLAIN).num


def test_the_noisy_depth_preset_is_ours_with_the_surface_estimate():
    """`--preset noisy-depth` (segment) and the bench method `ours-noisy-depth` are ours with the
    surface estimate forced on instead of decided by the measured noise ("auto"), nothing else."""
    from clutt3r_core.evaluation.methods import method_config

    nd = PRESETS["noisy-depth"]
    assert nd.pointcloud.surface == "tsdf"
    assert dataclasses.replace(nd, pointcloud=dataclasses.replace(nd.pointcloud, surface="auto")) == SegmentConfig()
    assert method_config("ours-noisy-depth") == nd


@pytest.mark.parametrize("surface", ["voxel-mean", "tsdf", "auto"])
def test_a_scene_too_large_to_index_is_refused_by_both_fusions(surface):
    """Poses 100 km apart (a unit mix-up): one clear SceneError, from the shared voxel keys,
    before the surface estimate does any work on a grid it cannot index."""
    views = make_views(2, 80, 60, 100.0)
    T = views[1].camera.T_world_camera.copy()
    T[0, 3] += 1e5
    cam = views[1].camera
    views[1] = dataclasses.replace(views[1], camera=Camera(cam.K, cam.width, cam.height, T))
    with pytest.raises(SceneError, match="too large to index"):
        fuse_views(views, PointCloudConfig(surface=surface))
