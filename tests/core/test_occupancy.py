from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.occupancy import OccupancyConfig, mask_occupancy, mask_voxel_hits
from clutt3r_core.pointcloud import FusedCloud, fuse_views
from clutt3r_core.supervoxels import SuperVoxelConfig, SuperVoxels, build_supervoxels
from tests.core._geometry_scenes import make_views


@pytest.fixture(scope="module")
def scene():
    views = make_views(2)
    cloud = fuse_views(views)
    return views, cloud, build_supervoxels(cloud)


def _visible_sv(cloud, sv, v):
    return np.bincount(sv.labels, weights=cloud.visible()[v], minlength=sv.num) > 0


def test_full_and_empty_masks(scene):
    views, cloud, sv = scene
    for v in range(2):
        shape = cloud.pixel_voxel[v].shape
        occ = mask_occupancy(cloud, sv, v, np.stack([np.ones(shape, bool), np.zeros(shape, bool)]))
        assert occ.shape == (2, sv.num) and occ.dtype == np.float32
        vis = _visible_sv(cloud, sv, v)
        np.testing.assert_allclose(occ[0, vis], 1.0, atol=1e-6)
        assert (occ[0, ~vis] == 0).all()
        assert (occ[1] == 0).all()
        # paper-literal normalisation never exceeds the visible one
        lit = mask_occupancy(cloud, sv, v, np.ones((1,) + shape, bool), OccupancyConfig(normalise="all"))
        assert (lit <= occ[:1] + 1e-6).all() and lit[0, vis].min() > 0


def test_box_mask_occupies_box_supervoxels(scene):
    views, cloud, sv = scene
    occ = mask_occupancy(cloud, sv, 0, views[0].masks.masks)  # [box, table]
    box_sv = np.unique(sv.labels[cloud.points[:, 2] > 0.079])
    assert occ[0, box_sv].max() > 0.9 and occ[1, box_sv].max() < 0.1
    table_sv = np.unique(sv.labels[np.abs(cloud.points[:, :2]).max(axis=1) > 0.2])
    table_sv = table_sv[_visible_sv(cloud, sv, 0)[table_sv]]
    assert len(table_sv) and occ[1, table_sv].min() > 0.9 and occ[0, table_sv].max() == 0


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), m=st.integers(0, 4), p=st.floats(0.0, 1.0))
def test_random_masks_occupancy_in_unit_interval_and_hits_count_pixels(scene, seed, m, p):
    views, cloud, sv = scene
    shape = cloud.pixel_voxel[1].shape
    masks = np.random.default_rng(seed).random((m,) + shape) < p
    hits = mask_voxel_hits(cloud, 1, masks)
    assert hits.shape == (m, cloud.num) and hits.data.dtype == np.float32
    fed = cloud.pixel_voxel[1] >= 0
    np.testing.assert_array_equal(hits.row_sums(), (masks & fed).reshape(m, fed.size).sum(axis=1))
    # dense reference: pixels of mask m that fed voxel n, counted one by one
    pv = cloud.pixel_voxel[1]
    dense = np.zeros((m, cloud.num), np.float32)
    for i in range(m):
        np.add.at(dense[i], pv[masks[i] & fed], 1.0)
    np.testing.assert_array_equal(hits.toarray(), dense)
    # canonical order (sorted by row, then column; unique, non-zero): what the sums rely on
    key = hits.row * cloud.num + hits.col
    assert (np.diff(key) > 0).all() and (hits.data > 0).all()
    x = np.random.default_rng(seed + 1).random(cloud.num)
    np.testing.assert_allclose(hits.matvec(x), dense.astype(np.float64) @ x, rtol=1e-12)
    np.testing.assert_array_equal(hits.tocsr().toarray(), dense)
    occ = mask_occupancy(cloud, sv, 1, masks)
    assert occ.shape == (m, sv.num)
    assert (occ >= 0).all() and (occ <= 1).all()


def test_hand_computed_occupancy():
    # voxels 0, 1 in super-voxel 0; voxel 2 alone. View 0: 2x2 image, pixels feed voxels 0, 0, 2, -1.
    # Voxel 1 is not seen by view 0 (only by view 1).
    pts = np.array([[0, 0, 0], [0.005, 0, 0], [0.5, 0, 0]], float)
    cloud = FusedCloud(
        pts, np.zeros((3, 3), np.uint8), np.tile([0, 0, 1.0], (3, 1)), np.array([4, 6, 2]), 0.005, (0, 1),
        (np.array([[0, 0], [2, -1]], np.int32), np.array([[1, -1], [-1, -1]], np.int32)),
    )
    sv = SuperVoxels(np.array([0, 0, 1]), np.array([10, 2]), np.array([10, 2]) / 12, np.zeros(2, bool))
    mask = np.array([[[True, False], [True, True]]])  # half of voxel 0's pixels, all of voxel 2's
    occ = mask_occupancy(cloud, sv, 0, mask)
    np.testing.assert_allclose(occ, [[0.5, 1.0]])  # visible part of sv 0 is voxel 0 only
    occ_all = mask_occupancy(cloud, sv, 0, mask, OccupancyConfig(normalise="all"))
    np.testing.assert_allclose(occ_all, [[0.5 * 4 / 10, 1.0]])
    hits = mask_voxel_hits(cloud, 0, mask).toarray()
    np.testing.assert_array_equal(hits, [[1, 0, 1]])


def test_bad_input(scene):
    views, cloud, sv = scene
    with pytest.raises(SceneError):
        mask_occupancy(cloud, sv, 5, views[0].masks.masks)
    with pytest.raises(SceneError):
        mask_voxel_hits(cloud, 0, np.zeros((1, 3, 3), bool))
    with pytest.raises(SceneError):
        OccupancyConfig(normalise="some")  # type: ignore[arg-type]


@pytest.mark.realdata
@pytest.mark.parametrize("which", ["seq1_dir", "seq4_dir"])
def test_real_samples_occupancy(which, request):
    from clutt3r_core.io.sample_layout import load_sample_layout

    scene = load_sample_layout(request.getfixturevalue(which), load_gt=False)
    views = scene.initial_views
    cloud = fuse_views(views)
    sv = build_supervoxels(cloud, SuperVoxelConfig())
    for i, v in enumerate(views[:3]):
        occ = mask_occupancy(cloud, sv, i, v.masks.masks)
        assert occ.shape == (len(v.masks), sv.num)
        assert (occ >= 0).all() and (occ <= 1).all()
        # every real mask lands on something, and mostly on non-support super-voxels
        assert (occ.max(axis=1) > 0.5).all()
