"""Rim voxels of the surface estimate (``PointCloudConfig.surface_rim_neighbours``, issue 13): the fusion."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.config import ADDED_AFTER_V1, ADDITIONS, PRESETS, SegmentConfig
from clutt3r_core.errors import SceneError
from clutt3r_core.pointcloud import PointCloudConfig, _group_keys, _voxel_keys, fuse_views
from clutt3r_core.surface import _kept_neighbours
from tests.core._geometry_scenes import make_views


def _noisy(views, sigma: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    return [dataclasses.replace(v, depth=v.depth + rng.normal(0.0, sigma, v.depth.shape).astype(np.float32))
            for v in views]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 60), st.floats(0.0, 1.0))
def test_kept_neighbours_counts_the_26_neighbourhood(seed, n, frac):
    """Against a brute-force count over the distinct voxels of random points."""
    rng = np.random.default_rng(seed)
    P = (rng.integers(0, 5, (n, 3)) * 0.01 + 0.005 + rng.uniform(-0.004, 0.004, (n, 3))).astype(np.float32)
    keys, _, ext = _voxel_keys(P, 0.01, pad=1)
    inverse, counts = _group_keys(keys, ext)
    u = len(counts)
    kept = rng.random(u) < frac
    cand = np.arange(u)
    got = _kept_neighbours(keys, ext, inverse, kept, cand)
    vk = np.zeros((u, 3), np.int64)
    vk[inverse] = np.stack(keys, axis=1)
    want = [int(sum(kept[j] for j in range(u) if j != i and np.abs(vk[j] - vk[i]).max() <= 1)) for i in range(u)]
    assert got.tolist() == want


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 400), st.floats(0.0, 1.0), st.integers(1, 4))
def test_kept_neighbours_grid_and_search_agree(seed, n, frac, cells):
    """The dense-grid lookups (the usual path) and the binary searches (scenes too large for the grid)
    count the same neighbours, candidates in any order and repeated."""
    import clutt3r_core.pointcloud as pc

    rng = np.random.default_rng(seed)
    P = (rng.integers(0, 12, (n, 3)) * 0.005 + rng.uniform(0, 0.005, (n, 3))).astype(np.float32)
    keys, _, ext = _voxel_keys(P, 0.005, pad=1)
    inverse, counts = _group_keys(keys, ext)
    kept = rng.random(len(counts)) < frac
    cand = rng.integers(0, len(counts), 2 * len(counts))
    grid = _kept_neighbours(keys, ext, inverse, kept, cand)
    with pytest.MonkeyPatch.context() as mp:  # grids of at most 1-4 cells: the search path
        mp.setattr(pc, "_DENSE_GRID_CELLS", cells)
        search = _kept_neighbours(keys, ext, inverse, kept, cand)
    assert grid.dtype == search.dtype and grid.tolist() == search.tolist()


def test_rim_fill_only_adds_lone_voxels_next_to_the_surface():
    """With noisy depth the fill adds voxels (the box's rims), each holding one raw point and
    bordering a voxel of the cloud without the fill; every voxel of that cloud is kept unchanged."""
    views = _noisy(make_views(3, 320, 240, 400.0), 0.003)
    base = fuse_views(views, PointCloudConfig(surface="tsdf", surface_rim_neighbours=0))
    fill = fuse_views(views, PointCloudConfig(surface="tsdf", surface_rim_neighbours=1, surface_rim_attach_k=0))
    assert fill.rim is None and fill.surface.rim == 0  # joined the cloud
    vs = base.voxel_size
    kb = np.floor(base.points / vs).astype(np.int64)
    kf = np.floor(fill.points / vs).astype(np.int64)
    index = {tuple(k): i for i, k in enumerate(kf)}
    rows = np.array([index[tuple(k)] for k in kb])  # every base voxel is in the filled cloud ...
    np.testing.assert_allclose(fill.points[rows], base.points, atol=1e-6)  # ... with the same mean
    np.testing.assert_array_equal(fill.counts[rows], base.counts)
    added = np.setdiff1d(np.arange(fill.num), rows)
    assert len(added) > 0
    assert (fill.counts[added] == 1).all()
    bset = {tuple(k) for k in kb}
    offs = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1) if (a, b, c) != (0, 0, 0)]
    assert all(any(tuple(kf[i] + o) in bset for o in offs) for i in added)
    # a stricter neighbour count adds a subset
    strict = fuse_views(views, PointCloudConfig(surface="tsdf", surface_rim_neighbours=6, surface_rim_attach_k=0))
    assert base.num <= strict.num <= fill.num
    # kept apart (the default): the cloud is exactly the one without the fill, the rim the added voxels
    apart = fuse_views(views, PointCloudConfig(surface="tsdf", surface_rim_neighbours=1))
    for f in ("points", "colors", "normals", "counts", "visibility", "neighbours"):
        np.testing.assert_array_equal(getattr(apart, f), getattr(base, f), err_msg=f)
    for v in range(len(views)):
        for a, b in zip(apart.pixel_voxel.pixels(v), base.pixel_voxel.pixels(v)):
            np.testing.assert_array_equal(a, b)
    assert apart.rim is not None and apart.rim.num == len(added) == apart.surface.rim
    got = sorted(map(tuple, np.floor(apart.rim.points / vs).astype(np.int64)))
    assert got == sorted(map(tuple, kf[added]))
    np.testing.assert_allclose(np.linalg.norm(apart.rim.normals, axis=1), 1.0, atol=1e-5)
    assert (apart.rim.counts == 1).all()


def test_rim_config_defaults_and_ablation():
    """On in ours (an addition: the paper preset and ``ours-no-rim-attach`` set 0), kept apart and
    attached with k = 6 within 20 mm; a stored config older than the fields gets 0 / joined (as the
    code that wrote it); bad values are refused."""
    with pytest.raises(SceneError, match="surface_rim_neighbours"):
        PointCloudConfig(surface_rim_neighbours=-1)
    with pytest.raises(SceneError, match="surface_rim_attach"):
        PointCloudConfig(surface_rim_attach_k=-1)
    with pytest.raises(SceneError, match="surface_rim_attach"):
        PointCloudConfig(surface_rim_attach_distance=float("nan"))
    pc = SegmentConfig().pointcloud
    assert (pc.surface_rim_neighbours, pc.surface_rim_attach_k, pc.surface_rim_attach_distance) == (1, 6, 0.02)
    assert PRESETS["paper"].pointcloud.surface_rim_neighbours == 0
    assert ("pointcloud.surface_rim_neighbours", 1, 0) in {f for a in ADDITIONS for f in a.fields}
    assert ADDED_AFTER_V1["pointcloud.surface_rim_attach_k"] == 0


def test_clean_depth_has_no_rim():
    """``auto`` leaves clean depth to the plain fusion: no rim voxels, the same cloud as before."""
    views = make_views(3, 320, 240, 400.0)
    cloud = fuse_views(views, PointCloudConfig())
    assert cloud.surface.method == "voxel-mean" and cloud.rim is None and cloud.surface.rim == 0


# ---- session 9 (the holes): two wider rim rules, off by default (docs/benchmark/strict-iou.md)


@pytest.mark.parametrize("extra", [{"surface_rim_moved": 1}, {"surface_rim_reach": 0.015}])
def test_wider_rim_rules_add_rim_voxels_only(extra):
    """``surface_rim_moved`` / ``surface_rim_reach`` add rim voxels (each one point) and change
    nothing else: the segmented cloud is the default's, the default's rim voxels stay; a lone
    moved voxel added borders a cloud voxel, a voxel added by the reach has a cloud voxel within
    the reach and none among its 26 neighbours."""
    views = _noisy(make_views(3, 320, 240, 400.0), 0.003)
    base = fuse_views(views, PointCloudConfig(surface="tsdf"))
    more = fuse_views(views, PointCloudConfig(surface="tsdf", **extra))
    for f in ("points", "colors", "normals", "counts", "visibility", "neighbours"):
        np.testing.assert_array_equal(getattr(more, f), getattr(base, f), err_msg=f)
    vs = base.voxel_size
    kb = {tuple(k) for k in np.floor(base.rim.points / vs).astype(np.int64)}
    km = {tuple(k) for k in np.floor(more.rim.points / vs).astype(np.int64)}
    assert kb < km and more.rim.num == len(km) == more.surface.rim
    assert (more.rim.counts == 1).all()
    added = np.array(sorted(km - kb))
    cloud = np.floor(base.points / vs).astype(np.int64)
    cheb = np.abs(added[:, None, :] - cloud[None, :, :]).max(axis=2).min(axis=1)
    if "surface_rim_moved" in extra:
        assert (cheb == 1).all()
    else:
        euc = np.sqrt(((added[:, None, :] - cloud[None, :, :]) ** 2).sum(axis=2)).min(axis=1)
        assert (cheb >= 2).all() and (euc <= 0.015 / vs + 1e-9).all()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 80), st.floats(0.0, 1.0), st.floats(0.0, 4.0))
def test_near_kept_against_brute_force(seed, n, frac, reach):
    """``_near_kept``: the candidates with a kept voxel key within ``reach`` voxel edges."""
    from clutt3r_core.surface import _near_kept

    rng = np.random.default_rng(seed)
    P = (rng.integers(0, 8, (n, 3)) * 0.005 + rng.uniform(0, 0.005, (n, 3))).astype(np.float32)
    keys, _, ext = _voxel_keys(P, 0.005, pad=1)
    inverse, counts = _group_keys(keys, ext)
    u = len(counts)
    kept = rng.random(u) < frac
    cand = np.flatnonzero(~kept)
    got = _near_kept(keys, inverse, kept, cand, reach)
    vk = np.zeros((u, 3), np.int64)
    vk[inverse] = np.stack(keys, axis=1)
    want = [i for i in cand if kept.any() and np.sqrt(((vk[kept] - vk[i]) ** 2).sum(axis=1)).min() <= reach + 1e-9]
    assert got.tolist() == want


def test_wider_rim_rules_config():
    """Off in ours and in stored configs older than the fields; bad values refused."""
    with pytest.raises(SceneError, match="surface_rim_moved"):
        PointCloudConfig(surface_rim_moved=-1)
    with pytest.raises(SceneError, match="surface_rim_reach"):
        PointCloudConfig(surface_rim_reach=float("nan"))
    pc = SegmentConfig().pointcloud
    assert (pc.surface_rim_moved, pc.surface_rim_reach) == (0, 0.0)
    assert ADDED_AFTER_V1["pointcloud.surface_rim_moved"] == 0
    assert ADDED_AFTER_V1["pointcloud.surface_rim_reach"] == 0.0
