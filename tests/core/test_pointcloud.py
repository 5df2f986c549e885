from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.pointcloud import FusedCloud, PointCloudConfig, _backproject_strided, auto_stride, fuse_views
from clutt3r_core.scene import Camera, View
from tests.core._geometry_scenes import BOX_MAX, make_views


@settings(max_examples=40, deadline=None)
@given(
    yaw=st.floats(-np.pi, np.pi),
    pitch=st.floats(-1.2, 1.2),
    tx=st.floats(-2, 2),
    ty=st.floats(-2, 2),
    tz=st.floats(-2, 2),
    f=st.floats(50, 2000),
    seed=st.integers(0, 2**31 - 1),
)
def test_backproject_project_round_trip(yaw, pitch, tx, ty, tz, f, seed):
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    R = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]]) @ np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, (tx, ty, tz)
    cam = Camera(np.array([[f, 0, 15.5], [0, f * 1.1, 11.5], [0, 0, 1]]), 32, 24, T)
    depth = np.random.default_rng(seed).uniform(0.1, 3.0, (24, 32)).astype(np.float32)
    depth[3, 4] = np.nan
    pts, pix = cam.backproject(depth)
    uv, z = cam.project(pts)
    assert len(pix) == 32 * 24 - 1
    np.testing.assert_allclose(uv[:, 0], pix % 32, atol=1e-6)
    np.testing.assert_allclose(uv[:, 1], pix // 32, atol=1e-6)
    np.testing.assert_allclose(z, depth.reshape(-1)[pix], rtol=1e-9)


@settings(max_examples=40, deadline=None)
@given(stride=st.integers(1, 5), holes=st.floats(0, 1), seed=st.integers(0, 2**31 - 1),
       f64=st.booleans(), yaw=st.floats(-np.pi, np.pi))
def test_strided_backprojection_matches_the_camera(stride, holes, seed, f64, yaw):
    """The fusion's float32 grid back-projection (per-row / per-column factors) gives the valid
    pixels of ``Camera.backproject`` on the same stride grid, range filter applied, in
    row-major order, at float32 precision."""
    rng = np.random.default_rng(seed)
    T = np.eye(4)
    T[:3, :3] = [[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]]
    T[:3, 3] = rng.uniform(-1, 1, 3)
    cam = Camera(np.array([[300.0, 0, 15.5], [0, 310.0, 11.5], [0, 0, 1]]), 33, 25, T)
    depth = rng.uniform(0.05, 4.0, (25, 33))
    depth[rng.random(depth.shape) < holes] = np.nan
    depth = depth if f64 else depth.astype(np.float32)
    cfg = PointCloudConfig(min_depth=0.2, max_depth=3.0)
    pw, pix = _backproject_strided(View(0, np.zeros((25, 33, 3), np.uint8), cam, depth=depth), stride, cfg)
    ref, ref_pix = cam.backproject(depth.astype(np.float32).astype(np.float64), stride=stride)
    z = depth.reshape(-1)[ref_pix].astype(np.float32)
    keep = (z >= cfg.min_depth) & (z <= cfg.max_depth)
    np.testing.assert_array_equal(pix, ref_pix[keep])
    assert pw.dtype == np.float32 and pw.shape == (int(keep.sum()), 3)
    np.testing.assert_allclose(pw, ref[keep], atol=1e-5)


def test_fused_points_lie_on_the_scene_and_provenance_is_consistent():
    views = make_views(2, width=320, height=240, f=400.0)  # about 10 pixels per voxel per view
    cfg = PointCloudConfig(min_points=3)
    cloud = fuse_views(views, cfg)
    assert cloud.num > 1000 and cloud.frames == (0, 1) and cloud.stride == (1, 1)
    assert cloud.points.dtype == np.float32 and cloud.colors.dtype == np.uint8 and cloud.counts.dtype == np.int32
    assert (cloud.counts >= 3).all()
    p = cloud.points
    # every voxel mean lies on the table (z = 0) or on the box (a voxel straddling the
    # box's foot mixes both, so allow one voxel around the box)
    on_table = np.abs(p[:, 2]) < 1e-4
    in_box = (np.abs(p[:, :2]) <= BOX_MAX[:2] + cfg.voxel_size).all(axis=1) & (p[:, 2] <= BOX_MAX[2] + 1e-4)
    assert (on_table | in_box).all()
    for i, view in enumerate(views):
        pv = cloud.pixel_voxel[i]
        assert pv.shape == view.depth.shape and pv.dtype == np.int32
        pts, pix = view.camera.backproject(view.depth)
        vox = pv.reshape(-1)[pix]
        fed = vox >= 0
        assert fed.mean() > 0.9  # only pixels of sparse voxels are dropped
        # a pixel's point lies in the voxel it fed: within one voxel diagonal of the mean
        d = np.linalg.norm(pts[fed] - cloud.points[vox[fed]], axis=1)
        assert d.max() <= np.sqrt(3) * cfg.voxel_size + 1e-6
        assert (pv.reshape(-1)[np.isnan(view.depth.reshape(-1))] == -1).all()
        vis = np.zeros(cloud.num, bool)
        vis[vox[fed]] = True
        np.testing.assert_array_equal(cloud.visible()[i], vis)
    # counts are the raw points of the kept voxels: fed pixels of all views
    assert cloud.counts.sum() == sum(int((pv >= 0).sum()) for pv in cloud.pixel_voxel)
    # colours: box voxels red, table voxels grey
    assert (cloud.colors[on_table & ~in_box] == 200).all()
    top = np.abs(p[:, 2] - BOX_MAX[2]) < 1e-4
    assert top.sum() > 50 and (cloud.colors[top] == (200, 30, 30)).all()


def test_normals_are_unit_and_face_the_cameras():
    views = make_views(2)
    cloud = fuse_views(views)
    np.testing.assert_allclose(np.linalg.norm(cloud.normals, axis=1), 1.0, atol=1e-5)
    centres = np.stack([v.camera.T_world_camera[:3, 3] for v in views])
    np.testing.assert_allclose(cloud.camera_centres, centres)
    vis = cloud.visible().astype(float)
    cam_mean = vis.T @ centres / vis.sum(0)[:, None]
    assert (np.einsum("ij,ij->i", cloud.normals, cam_mean - cloud.points) >= 0).all()
    # the open table far from the box has normals +z
    far = (np.abs(cloud.points[:, 2]) < 1e-4) & (np.abs(cloud.points[:, :2]).max(axis=1) > 0.1)
    assert np.median(cloud.normals[far, 2]) > 0.99


@settings(max_examples=6, deadline=None)
@given(perm=st.permutations([0, 1, 2]))
def test_voxel_means_do_not_depend_on_view_order(perm):
    views = make_views(3, width=80, height=60, f=100.0)
    cfg = PointCloudConfig(min_points=2)
    ref = fuse_views(views, cfg)
    other = fuse_views([views[i] for i in perm], cfg)
    assert other.frames == tuple(perm)
    np.testing.assert_allclose(other.points, ref.points, atol=1e-6)
    np.testing.assert_array_equal(other.counts, ref.counts)
    np.testing.assert_array_equal(other.colors, ref.colors)
    for j, i in enumerate(perm):
        np.testing.assert_array_equal(other.pixel_voxel[j], ref.pixel_voxel[i])


def test_stride_and_min_points():
    assert auto_stride(480, 640) == 1 and auto_stride(120, 160) == 1
    assert auto_stride(1080, 1920) == 3 and auto_stride(720, 1280) == 2
    views = make_views(1)
    c2 = fuse_views(views, PointCloudConfig(pixel_stride=2, min_points=1))
    pv = c2.pixel_voxel[0]
    assert c2.stride == (2,)
    assert (pv[1::2, :] == -1).all() and (pv[:, 1::2] == -1).all()
    assert (pv[::2, ::2] >= 0).mean() > 0.99
    c1 = fuse_views(views, PointCloudConfig(min_points=1))
    c5 = fuse_views(views, PointCloudConfig(min_points=5))
    assert c5.num < c1.num and (c5.counts >= 5).all()


def test_range_filter_holes_and_errors():
    v = make_views(1)[0]
    depth = v.depth.copy()
    depth[:10] = np.nan
    depth[10:20] = 0.0
    hole = View(frame=0, rgb=v.rgb, camera=v.camera, depth=depth)
    c = fuse_views([hole], PointCloudConfig(min_points=1, max_depth=0.62))
    pv = c.pixel_voxel[0]
    assert (pv[:20] == -1).all()
    assert (pv[hole.depth > 0.62] == -1).all()
    with pytest.raises(SceneError):
        fuse_views([View(frame=0, rgb=v.rgb, camera=v.camera)])
    with pytest.raises(SceneError):
        fuse_views([])
    with pytest.raises(SceneError):
        PointCloudConfig(voxel_size=0)
    with pytest.raises(SceneError):
        FusedCloud(np.zeros((2, 3)), np.zeros((2, 3), np.uint8), np.zeros((2, 3)), np.ones(2), 0.005, (0,),
                   (np.full((2, 2), 5, np.int32),))


@pytest.mark.realdata
@pytest.mark.parametrize("which", ["seq1_dir", "seq4_dir"])
def test_real_samples_fuse(which, request):
    from clutt3r_core.io.sample_layout import load_sample_layout

    scene = load_sample_layout(request.getfixturevalue(which), load_masks=False, load_gt=False)
    cloud = fuse_views(scene.initial_views)
    assert 50_000 < cloud.num < 400_000
    assert len(cloud.pixel_voxel) == len(scene.initial)
    assert cloud.visible().any(axis=0).all()  # every kept voxel was seen
    # the scene is a tabletop about a metre across at most
    ext = np.percentile(cloud.points, 99, axis=0) - np.percentile(cloud.points, 1, axis=0)
    assert (ext < 2.5).all()


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), n=st.integers(0, 40), per=st.sampled_from([1, 3, 514, 515, 900]))
def test_packed_colour_sums_equal_the_per_channel_sums(seed, n, per):
    # Invariant (issue 13, session 6): the fusion's packed colour sums are the per-channel integer
    # sums, at and above the packing's count limit (514 points per voxel), with a dropped bin n
    # that overflows the packed fields
    from clutt3r_core.pointcloud import _COLOUR_PACK_MAX_COUNT, _colour_sums

    rng = np.random.default_rng(seed)
    vox = np.concatenate([rng.integers(0, max(n, 1), n * 3), np.full(per if n else 0, max(n - 1, 0)),
                          np.full(2000, n)]).astype(np.intp)
    rng.shuffle(vox)
    C = rng.integers(0, 256, (len(vox), 3)).astype(np.uint8)
    C[vox == n] = 255
    want = np.stack([np.bincount(vox, weights=C[:, a], minlength=n + 1)[:n] for a in range(3)], axis=1)
    max_count = int(np.bincount(vox, minlength=n + 1)[:n].max()) if n else 0
    got = _colour_sums(vox, C, n, max_count)
    assert got.dtype == np.float64 and got.shape == (n, 3)
    assert np.array_equal(got, want)
    if n and per > _COLOUR_PACK_MAX_COUNT:  # the unpacked path was taken too
        assert max_count > _COLOUR_PACK_MAX_COUNT


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), ext=st.tuples(st.integers(1, 300), st.integers(1, 300), st.integers(1, 300)),
       n=st.integers(1, 3000))
def test_group_keys_is_np_unique_whichever_pair_goes_first(seed, ext, n):
    # Invariant: the voxels come in np.unique's order of the packed key and every point maps to
    # its own voxel, whichever pair of axes the dense passes take first (or the np.unique fallback)
    from clutt3r_core.pointcloud import _group_keys

    rng = np.random.default_rng(seed)
    keys = [rng.integers(0, e, n).astype(np.int32) for e in ext]
    inverse, counts = _group_keys(keys, np.asarray(ext, np.int64))
    lin = keys[0].astype(np.int64) + ext[0] * (keys[1].astype(np.int64) + ext[1] * keys[2].astype(np.int64))
    _, want_inv, want_counts = np.unique(lin, return_inverse=True, return_counts=True)
    assert np.array_equal(inverse, want_inv.reshape(-1)) and np.array_equal(counts, want_counts)


def test_auto_disagreement_beside_the_fusion_surfaces_its_error(monkeypatch):
    # auto's depth disagreement runs on a second thread (session 6); its error reaches the caller,
    # and a view without depth is refused before it starts
    import clutt3r_core.surface as surface

    views = make_views(2)

    def broken(*a, **k):
        raise RuntimeError("disagreement failed")

    monkeypatch.setattr(surface, "auto_disagreement", broken)
    with pytest.raises(RuntimeError, match="disagreement failed"):
        fuse_views(views, PointCloudConfig(surface="auto"))
    assert fuse_views(views, PointCloudConfig(surface="voxel-mean")).num > 0  # not measured there
    from dataclasses import replace as dc_replace

    with pytest.raises(SceneError, match="without depth"):
        fuse_views([views[0], dc_replace(views[1], depth=None)], PointCloudConfig(surface="auto"))
