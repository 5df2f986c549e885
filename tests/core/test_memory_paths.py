"""The 1080p memory work of issue 13 keeps every result: sparse pixel->voxel maps, int32
k-NN edges, and the appearance histograms computed with one reused int32 key array."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.embeddings import AppearanceEmbedder
from clutt3r_core.pointcloud import FusedCloud, PixelVoxelMaps, fuse_views
from clutt3r_core.supervoxels import _knn_edges

from ._geometry_scenes import make_views


@settings(max_examples=40, deadline=None)
@given(h=st.integers(1, 12), w=st.integers(1, 12), seed=st.integers(0, 2**16), frac=st.floats(0.0, 1.0))
def test_pixel_voxel_maps_round_trip(h, w, seed, frac):
    """Property: dense map -> sparse pairs -> dense map is the identity; pairs ascend by pixel."""
    rng = np.random.default_rng(seed)
    dense = np.where(rng.random((h, w)) < frac, rng.integers(0, 50, (h, w)), -1).astype(np.int32)
    maps = PixelVoxelMaps.from_dense([dense, dense[::-1]])
    assert len(maps) == 2 and maps.shapes == ((h, w), (h, w))
    np.testing.assert_array_equal(maps[0], dense)
    np.testing.assert_array_equal(maps[-1], dense[::-1])
    pix, vox = maps.pixels(0)
    assert pix.dtype == vox.dtype == np.int32 and np.all(np.diff(pix) > 0)
    np.testing.assert_array_equal(vox, dense.reshape(-1)[pix])
    assert not maps[0].flags.writeable
    with pytest.raises(IndexError):
        maps[2]


def test_fused_cloud_pixels_match_its_dense_maps():
    cloud = fuse_views(make_views(3))
    assert isinstance(cloud.pixel_voxel, PixelVoxelMaps)
    for v in range(len(cloud.frames)):
        dense = cloud.pixel_voxel[v]
        pix, vox = cloud.pixel_voxel.pixels(v)
        np.testing.assert_array_equal(pix, np.flatnonzero(dense.reshape(-1) >= 0))
        np.testing.assert_array_equal(vox, dense.reshape(-1)[pix])
        assert cloud.visibility[v, vox].all() and cloud.visibility[v].sum() == len(np.unique(vox))
    # a cloud built from the dense maps is the same cloud
    again = FusedCloud(cloud.points, cloud.colors, cloud.normals, cloud.counts, cloud.voxel_size, cloud.frames,
                       [cloud.pixel_voxel[v] for v in range(len(cloud.frames))], cloud.stride)
    np.testing.assert_array_equal(again.visibility, cloud.visibility)
    for v in range(len(cloud.frames)):
        for a, b in zip(again.pixel_voxel.pixels(v), cloud.pixel_voxel.pixels(v)):
            np.testing.assert_array_equal(a, b)


def test_dense_maps_are_still_checked():
    with pytest.raises(Exception, match="outside"):
        FusedCloud(np.zeros((2, 3)), np.zeros((2, 3), np.uint8), np.zeros((2, 3)), np.ones(2), 0.005, (0,),
                   [np.array([[0, 5]], np.int32)])


def test_knn_edges_int32_and_exact():
    rng = np.random.default_rng(1)
    pts = rng.random((300, 3)) * 0.1
    src, dst, dist = _knn_edges(pts, 6, 0.02)
    assert src.dtype == dst.dtype == np.int32 and dist.dtype == np.float64
    np.testing.assert_allclose(dist, np.linalg.norm(pts[src] - pts[dst], axis=1), rtol=1e-12)
    assert (src != dst).all() and (dist <= 0.02).all()
    # brute force: each i's pairs are its nearest (up to 6) others within 2 cm
    d = np.linalg.norm(pts[:, None] - pts[None], axis=2)
    np.fill_diagonal(d, np.inf)
    for i in (0, 17, 299):
        want = set(np.argsort(d[i])[:6][np.sort(d[i])[:6] <= 0.02].tolist())
        assert set(dst[src == i].tolist()) == want


def _naive_histograms(emb: AppearanceEmbedder, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """The descriptor by its definition: per mask, joint (hue|grey, sat) and value histograms."""
    import cv2

    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(np.int64)
    hb = np.where(hsv[:, 1] >= emb.min_saturation, hsv[:, 0] * emb.hue_bins // 256, emb.hue_bins)
    joint = hb * emb.sat_bins + hsv[:, 1] * emb.sat_bins // 256
    vb = (emb.hue_bins + 1) * emb.sat_bins + hsv[:, 2] * emb.val_bins // 256
    out = np.zeros((len(masks), emb.dim))
    for i, m in enumerate(masks.reshape(len(masks), -1)):
        out[i] = np.bincount(joint[m], minlength=emb.dim) + np.bincount(vb[m], minlength=emb.dim)
    out = np.sqrt(out)
    n = np.linalg.norm(out, axis=1, keepdims=True)
    return np.divide(out, n, out=np.zeros_like(out), where=n > 0).astype(np.float32)


def test_appearance_histograms_equal_their_definition():
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (40, 50, 3), dtype=np.uint8)
    masks = rng.random((20, 40, 50)) < 0.3  # 20 masks: two 16-mask code chunks
    masks[3] = False  # an empty mask: zero descriptor
    emb = AppearanceEmbedder()
    np.testing.assert_array_equal(emb.embed_masks(rgb, masks), _naive_histograms(emb, rgb, masks))


@pytest.mark.parametrize("cfg, n_masks", [
    ({}, 5),                                                   # 8-bit planes and codes
    ({"hue_bins": 64, "sat_bins": 8, "val_bins": 300}, 20),    # 16-bit planes
    ({"hue_bins": 300, "sat_bins": 256, "min_saturation": 0}, 3),  # more than 2^16 bins: float32 planes
])
def test_appearance_histograms_of_candidates_equal_their_definition(cfg, n_masks):
    """The histograms from the candidates' code image (2D histograms of (set, bin)) are the
    definition's, for every plane depth; a stack and the candidates give the same rows."""
    from clutt3r_core.scene import MaskCandidates

    rng = np.random.default_rng(5)
    rgb = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    masks = rng.random((n_masks, 30, 40)) < 0.4
    emb = AppearanceEmbedder(**cfg)
    want = _naive_histograms(emb, rgb, masks)
    np.testing.assert_array_equal(emb.embed_masks(rgb, MaskCandidates(masks, np.arange(n_masks))), want)
    np.testing.assert_array_equal(emb.embed_masks(rgb, masks), want)
