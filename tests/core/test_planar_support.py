"""Rule-3-only support (``SuperVoxels.planar``) and its mask guard ``support.planar_covered``
(``SuperVoxelConfig.planar_mask_views``, ours, session 9), and the leaf edges after the
un-marking (``support.kept_spatial``, session 10)."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.pointcloud import FusedCloud
from clutt3r_core.supervoxels import SuperVoxelConfig, build_supervoxels
from clutt3r_core.segmentation.grouping import spatial_similarity
from clutt3r_core.support import kept_spatial, planar_covered


def _grid(x0, x1, y0, y1, z, step=0.005):
    x, y = np.meshgrid(np.arange(x0, x1, step), np.arange(y0, y1, step), indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(x.size, z)])


def _slab_scene() -> tuple[FusedCloud, np.ndarray, np.ndarray]:
    """A 0.8 m table at z = 0 and, 6 cm above it, a 0.4 m x 6 cm slab whose two halves' normals
    lean 10 degrees apart: two super-voxels (eq. 1 cuts at ~7 degrees), each 0.2 m long, but
    one planar patch of 0.4 m (rule 3 allows 30 degrees): the halves are support by rule 3
    alone. Returns (cloud, table voxel mask, slab voxel mask)."""
    table = _grid(-0.4, 0.4, -0.4, 0.4, 0.0)
    slab = _grid(-0.2, 0.2, 0.1, 0.16, 0.06)
    pts = np.vstack([table, slab])
    n = len(pts)
    nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
    t = np.deg2rad(5.0)
    left = np.arange(len(table), n)[slab[:, 0] < 0]
    right = np.arange(len(table), n)[slab[:, 0] >= 0]
    nrm[left] = (np.sin(t), 0.0, np.cos(t))
    nrm[right] = (-np.sin(t), 0.0, np.cos(t))
    cloud = FusedCloud(pts.astype(np.float32), np.zeros((n, 3), np.uint8), nrm.astype(np.float32),
                       np.full(n, 3), 0.005, (0,), (np.arange(n, dtype=np.int32).reshape(1, n),),
                       camera_centres=np.array([[0.0, 0.0, 1.0]]))
    is_table = np.zeros(n, bool)
    is_table[: len(table)] = True
    return cloud, is_table, ~is_table


def test_slab_halves_are_planar_only_support_and_the_table_is_not():
    cloud, is_table, is_slab = _slab_scene()
    sv = build_supervoxels(cloud, SuperVoxelConfig())
    assert sv.planar is not None and sv.planar.shape == (sv.num,)
    assert not (sv.planar & ~sv.support).any()  # planar is a subset of support
    slab_sv = np.unique(sv.labels[is_slab])
    table_sv = np.unique(sv.labels[is_table])
    assert len(slab_sv) == 2 and not np.isin(slab_sv, table_sv).any()
    assert sv.support[slab_sv].all() and sv.planar[slab_sv].all()  # rule 3 alone marked them
    assert sv.support[table_sv].all() and not sv.planar[table_sv].any()  # ground / own extent


def test_without_support_removal_nothing_is_planar():
    cloud, _, _ = _slab_scene()
    sv = build_supervoxels(cloud, SuperVoxelConfig(support_removal=False))
    assert not sv.support.any() and (sv.planar is None or not sv.planar.any())


def test_config_rejects_out_of_range_share():
    with pytest.raises(SceneError, match="planar_mask_views"):
        SuperVoxelConfig(planar_mask_views=1.5)


def test_covered_needs_two_views_and_the_share_of_those_that_see_it():
    planar = np.array([True, True, True, False])
    # masks: view 0 covers k0, k1, k3; view 1 covers k0; view 2 covers k1 (a background mask), k2
    occ = np.array([[0.9, 0.6, 0.0, 1.0],
                    [0.8, 0.0, 0.0, 1.0],
                    [0.0, 0.9, 0.0, 0.0],
                    [0.0, 0.0, 0.7, 0.0]], np.float32)
    view = np.array([0, 1, 2, 2])
    obj = np.array([True, True, False, True])
    visible = np.ones((3, 4), bool)
    out = planar_covered(planar, occ, view, obj, visible, 0.5)
    # k0: 2 of 3 views; k1: 1 (the background mask does not count); k2: 1; k3 is not planar
    assert out.tolist() == [True, False, False, False]
    assert planar_covered(planar, occ, view, obj, visible, 0.7).tolist() == [False] * 4  # 2/3 < 0.7
    vis2 = visible.copy()
    vis2[2, 0] = False  # a view that does not see k0 does not count against it
    assert planar_covered(planar, occ, view, obj, vis2, 1.0)[0]
    assert not planar_covered(planar, occ, view, obj, visible, 0.0).any()  # 0 = off


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), share=st.floats(0.05, 1.0))
def test_covered_is_planar_monotone_in_share(seed, share):
    # invariants: only planar super-voxels are un-marked, a larger share never un-marks more,
    # and more object masks never un-mark fewer
    rng = np.random.default_rng(seed)
    m, k, v = 12, 9, 4
    planar = rng.random(k) < 0.6
    occ = rng.random((m, k)).astype(np.float32)
    view = rng.integers(0, v, m)
    obj = rng.random(m) < 0.6
    visible = rng.random((v, k)) < 0.8
    out = planar_covered(planar, occ, view, obj, visible, share)
    assert not (out & ~planar).any()
    assert not (planar_covered(planar, occ, view, obj, visible, min(1.0, share + 0.2)) & ~out).any()
    assert not (out & ~planar_covered(planar, occ, view, obj | (rng.random(m) < 0.5), visible, share)).any()


def test_pipeline_guard_only_removes_support():
    # on a tiny generated scene the guard (any share) may only un-mark support super-voxels:
    # same super-voxels, support a subset of the default's, every instance label still valid
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from tests.core._tiny_run import tiny_scene, tiny_segmentation

    base = tiny_segmentation()
    seg = segment(tiny_scene(), with_fields(SegmentConfig(), {"supervoxels.planar_mask_views": 0.01}), progress=False)
    np.testing.assert_array_equal(seg.sv_labels, base.sv_labels)
    assert not (seg.sv_support & ~base.sv_support).any()
    assert seg.instance.max() < len(seg.scores)


def _excluding(occ: np.ndarray, support: np.ndarray, w: np.ndarray) -> np.ndarray:
    return spatial_similarity(np.where(support[None, :], 0.0, occ).astype(np.float32), w)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000))
def test_kept_spatial_keeps_the_first_edges_and_links_the_readmitted(seed):
    # invariants: pairs of first-object masks have the S_spatial of the support before the
    # un-marking; every pair with another mask has the S_spatial of the support after it; with
    # nothing un-marked it is the plain S_spatial over the non-support super-voxels
    rng = np.random.default_rng(seed)
    u, k = 10, 14
    occ = np.where(rng.random((u, k)) < 0.5, rng.random((u, k)), 0.0).astype(np.float32)
    w = rng.random(k) + 0.1
    w /= w.sum()
    first = rng.random(k) < 0.5
    support = first & (rng.random(k) < 0.5)
    first_object = rng.random(u) < 0.6
    s = kept_spatial(occ, w, support, first, first_object)
    before, after = _excluding(occ, first, w), _excluding(occ, support, w)
    keep = np.ix_(first_object, first_object)
    np.testing.assert_allclose(s[keep], before[keep], atol=1e-6)
    other = ~(first_object[:, None] & first_object[None, :])
    np.testing.assert_allclose(s[other], after[other], atol=1e-6)
    np.testing.assert_allclose(kept_spatial(occ, w, first, first, first_object), before, atol=1e-6)
    assert np.allclose(s, s.T, atol=1e-6)


def test_kept_spatial_rejects_support_that_grew():
    occ = np.ones((2, 3), np.float32)
    with pytest.raises(ValueError, match="subset"):
        kept_spatial(occ, np.full(3, 1 / 3), np.array([True, True, False]), np.array([True, False, False]),
                     np.ones(2, bool))


def test_pipeline_unmarking_keeps_the_default_masks_edges(monkeypatch):
    # every support super-voxel of the tiny scene made "rule 3 only", so that the guard un-marks
    # the table under its masks and re-admits them: the masks the default grouped keep exactly
    # the default's leaf edges, the re-admitted ones get edges of their own
    import dataclasses

    import clutt3r_core.pipeline as pl
    from clutt3r_core.config import SegmentConfig, with_fields
    from tests.core._tiny_run import tiny_scene

    build = pl.build_supervoxels
    monkeypatch.setattr(pl, "build_supervoxels", lambda cloud, cfg: (
        lambda sv: dataclasses.replace(sv, planar=sv.support.copy()))(build(cloud, cfg)))
    base = pl.segment(tiny_scene(), with_fields(SegmentConfig(), {"supervoxels.planar_mask_views": 0.0}),
                      progress=False)
    seg = pl.segment(tiny_scene(), with_fields(SegmentConfig(), {"supervoxels.planar_mask_views": 0.5}),
                     progress=False)
    assert (base.sv_support & ~seg.sv_support).any()  # something was un-marked
    first_object = ~base.trace.nodes.background
    readmitted = base.trace.nodes.background & ~seg.trace.nodes.background
    assert readmitted.any()
    keep = np.ix_(first_object, first_object)
    np.testing.assert_array_equal(seg.trace.s_spatial[keep], base.trace.s_spatial[keep])
    assert np.isfinite(seg.trace.s_spatial[np.ix_(readmitted, first_object)]).any()
