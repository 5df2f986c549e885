from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.pointcloud import FusedCloud, fuse_views
from clutt3r_core.supervoxels import SuperVoxelConfig, SuperVoxels, _knn_edges, build_supervoxels
from tests.core._geometry_scenes import BOX_MAX, make_views


@pytest.fixture(scope="module")
def table_box():
    cloud = fuse_views(make_views(3))
    return cloud, build_supervoxels(cloud)


def _line_cloud(normals: np.ndarray, spacing: float = 0.005) -> FusedCloud:
    n = len(normals)
    pts = np.zeros((n, 3))
    pts[:, 0] = np.arange(n) * spacing
    return FusedCloud(pts, np.zeros((n, 3), np.uint8), normals, np.full(n, 3), 0.005, (0,),
                      (np.arange(n, dtype=np.int32).reshape(1, n),))


def test_invariants(table_box):
    cloud, sv = table_box
    assert sv.labels.shape == (cloud.num,) and sv.labels.dtype == np.int32
    assert sv.labels.min() == 0 and sv.labels.max() == sv.num - 1
    assert np.bincount(sv.labels).min() >= 1  # no empty super-voxel
    assert sv.counts.sum() == cloud.counts.sum()
    np.testing.assert_allclose(sv.weights.sum(), 1.0)
    np.testing.assert_allclose(sv.weights, sv.counts / sv.counts.sum())
    assert sv.sizes.sum() == cloud.num
    assert sv.support.shape == (sv.num,) and sv.support.dtype == bool


def test_table_is_support_and_box_is_not(table_box):
    cloud, sv = table_box
    # the plane is the table z = 0, normal up towards the cameras
    np.testing.assert_allclose(sv.plane, [0, 0, 1, 0], atol=2e-3)
    vs = sv.voxel_support()
    z = cloud.points[:, 2]
    on_table = (np.abs(z) < 1e-4) & (np.abs(cloud.points[:, :2]).max(axis=1) > 0.06)
    assert vs[on_table].mean() > 0.99
    top = np.abs(z - BOX_MAX[2]) < 1e-4
    assert not vs[top].any()
    # the flat box top is (mostly) one super-voxel, and not the table's
    lab, cnt = np.unique(sv.labels[top], return_counts=True)
    assert cnt.max() > 0.8 * top.sum()
    assert lab[cnt.argmax()] not in set(sv.labels[on_table])
    # box sides are not support either
    side = (z > 0.01) & (z < BOX_MAX[2] - 0.01)
    assert not vs[side].any()


def test_paper_literal_marks_nothing():
    cloud = fuse_views(make_views(2))
    sv = build_supervoxels(cloud, SuperVoxelConfig(support_removal=False))
    assert sv.plane is None and not sv.support.any()


def test_tiny_tau_merge_gives_one_supervoxel_per_voxel():
    cloud = fuse_views(make_views(1, width=60, height=45, f=75.0))
    sv = build_supervoxels(cloud, SuperVoxelConfig(tau_merge=1e-6, support_removal=False))
    assert sv.num == cloud.num


def test_absolute_normal_dot_ignores_normal_sign():
    normals = np.tile([0.0, 0.0, 1.0], (6, 1))
    normals[::2] *= -1  # alternate signs: unoriented PCA normals
    cloud = _line_cloud(normals)
    assert build_supervoxels(cloud, SuperVoxelConfig(support_removal=False)).num == 1
    signed = build_supervoxels(cloud, SuperVoxelConfig(support_removal=False, absolute_normal_dot=False))
    # signed: only same-sign voxels (two apart, 1 cm) chain together
    assert signed.num == 2 and signed.labels.tolist() == [0, 1, 0, 1, 0, 1]


def test_eq1_threshold_on_distance_and_normal_angle():
    cfg = SuperVoxelConfig(support_removal=False)
    # 5 mm apart: 0.5 * 0.005 = 0.0025 <= 0.01; a 20 degree crease (1 - cos = 0.06) cuts
    n = np.tile([0.0, 0.0, 1.0], (4, 1))
    a = np.deg2rad(20)
    n[2:] = (np.sin(a), 0.0, np.cos(a))
    sv = build_supervoxels(_line_cloud(n), cfg)
    assert sv.num == 2 and sv.labels.tolist() == [0, 0, 1, 1]
    # 3 cm apart: 0.5 * 0.03 = 0.015 > 0.01 even with equal normals
    sv = build_supervoxels(_line_cloud(np.tile([0.0, 0.0, 1.0], (3, 1)), spacing=0.03), cfg)
    assert sv.num == 3


def test_validation():
    with pytest.raises(SceneError):
        SuperVoxelConfig(tau_merge=0)
    with pytest.raises(SceneError):
        SuperVoxels(np.array([0, 3]), np.ones(2), np.ones(2) / 2, np.zeros(2, bool))


@pytest.mark.realdata
@pytest.mark.parametrize("which", ["seq1_dir", "seq4_dir"])
def test_real_samples_supervoxels(which, request):
    from clutt3r_core.io.sample_layout import load_sample_layout

    scene = load_sample_layout(request.getfixturevalue(which), load_masks=False, load_gt=False)
    cloud = fuse_views(scene.initial_views)
    sv = build_supervoxels(cloud)
    assert 1000 < sv.num < cloud.num
    assert sv.plane is not None
    # the support is most of a tabletop view, but the objects are left
    frac = sv.voxel_support().mean()
    assert 0.5 < frac < 0.97
    assert (~sv.support & (sv.sizes >= 50)).sum() >= 5


def _edge_set(edges) -> set:
    src, dst, dist = edges
    return set(zip(src.tolist(), dst.tolist(), dist.tolist()))


def _table(means64: np.ndarray, k: int) -> np.ndarray:
    from scipy.spatial import cKDTree

    return cKDTree(means64).query(means64, k=k)[1].reshape(len(means64), k).astype(np.int32)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(2, 400), k=st.integers(1, 12),
       table_k=st.integers(1, 25), grid=st.booleans())
def test_knn_edges_from_the_neighbour_table_equal_the_query(seed, n, k, table_k, grid):
    """Issue 13: the super-voxel graph reuses the normals' k-NN table; its pairs and their
    lengths must be the bounded query's, also with exact distance ties at the cut (points on a
    grid) and with the table ranked on float64 means but the edges measured on float32 points."""
    rng = np.random.default_rng(seed)
    if grid:  # voxel means on a millimetre grid: many exactly equal distances
        means = rng.integers(0, 12, (n, 3)) * 0.004 + np.array([0.31, -0.2, 0.7])
    else:
        means = rng.random((n, 3)) * 0.08 + np.array([0.31, -0.2, 0.7]) + rng.normal(scale=1e-9, size=(n, 3))
    pts = means.astype(np.float32).astype(np.float64)  # what FusedCloud.points holds
    table = _table(means, min(table_k, n))
    for bound in (0.02, 0.008, np.inf):
        want = _edge_set(_knn_edges(pts, k, bound))
        got = _knn_edges(pts, k, bound, table)
        assert got[0].dtype == got[1].dtype == np.int32
        assert _edge_set(got) == want


def test_knn_edges_bound_is_strict_with_the_table():
    """A neighbour at exactly the bound is not an edge, as in cKDTree's bounded query."""
    pts = np.array([[0.0, 0.0, 0.0], [0.02, 0.0, 0.0], [0.0, 0.01, 0.0], [0.5, 0.5, 0.5]])
    table = _table(pts, 4)
    want = _edge_set(_knn_edges(pts, 3, 0.02))
    assert _edge_set(_knn_edges(pts, 3, 0.02, table)) == want
    assert (0, 1, 0.02) not in want and (0, 2, 0.01) in want


def test_fused_cloud_carries_the_normals_neighbours_and_supervoxels_are_unchanged(table_box):
    cloud, sv = table_box
    assert cloud.neighbours is not None and cloud.neighbours.shape == (cloud.num, 20)
    assert (cloud.neighbours[:, 0] == np.arange(cloud.num)).all()  # itself first
    bare = FusedCloud(cloud.points, cloud.colors, cloud.normals, cloud.counts, cloud.voxel_size, cloud.frames,
                      cloud.pixel_voxel, cloud.stride, camera_centres=cloud.camera_centres)
    again = build_supervoxels(bare)  # no table: its own query
    np.testing.assert_array_equal(again.labels, sv.labels)
    np.testing.assert_array_equal(again.support, sv.support)
    with pytest.raises(SceneError, match="neighbours"):
        FusedCloud(cloud.points, cloud.colors, cloud.normals, cloud.counts, cloud.voxel_size, cloud.frames,
                   cloud.pixel_voxel, neighbours=np.full((cloud.num, 3), cloud.num))


def test_support_planes_beside_give_the_planes_in_turn_and_errors_surface(table_box, monkeypatch):
    # the plane fits run on a second thread (session 6): mark_support with them equals mark_support
    # fitting them itself, and an error in the fits reaches the caller
    import clutt3r_core.supervoxels as sv_mod
    from clutt3r_core.support import mark_support, support_planes

    cloud, sv = table_box
    cfg = SuperVoxelConfig()
    src, dst, dist = _knn_edges(cloud.points.astype(np.float64), cfg.knn, 0.02, cloud.neighbours)
    planes = support_planes(cloud, cfg)
    assert planes.plane is not None and planes.ground.shape == (cloud.num,) and planes.uvh.shape == (cloud.num, 3)
    own = mark_support(cloud, sv.labels, sv.num, sv.counts, src, dst, dist, cfg)
    given_ = mark_support(cloud, sv.labels, sv.num, sv.counts, src, dst, dist, cfg, planes=planes)
    assert np.array_equal(own[0], given_[0]) and np.array_equal(own[1], given_[1])
    assert np.array_equal(own[0], sv.support) and np.array_equal(own[1], sv.plane)

    def broken(*a, **k):
        raise RuntimeError("plane fit failed")

    monkeypatch.setattr(sv_mod, "support_planes", broken)
    with pytest.raises(RuntimeError, match="plane fit failed"):
        build_supervoxels(cloud)
