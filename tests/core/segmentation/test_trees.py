from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.scene import MaskCandidates
from clutt3r_core.segmentation.trees import TreeConfig, build_instance_tree, mask_overlaps


def rect(h, w, r0, r1, c0, c1):
    m = np.zeros((h, w), bool)
    m[r0:r1, c0:c1] = True
    return m


def test_parent_with_two_children_and_partial_overlap():
    H, W = 40, 60
    union = rect(H, W, 5, 30, 5, 50)  # under-segmented pair
    a = rect(H, W, 5, 30, 5, 25)
    b = rect(H, W, 5, 30, 30, 50)
    part = rect(H, W, 10, 20, 8, 20)  # over-segmented part of a
    other = rect(H, W, 20, 39, 45, 59)  # overlaps union partially only
    mc = MaskCandidates(np.stack([union, a, b, part, other]), np.array([1, 2, 3, 4, 5]))
    t = build_instance_tree(mc, frame=0, cfg=TreeConfig(min_area_px=1))
    par = {int(t.mask_ids[i]): (int(t.mask_ids[p]) if p >= 0 else None) for i, p in enumerate(t.parent)}
    assert par == {1: None, 2: 1, 3: 1, 4: 2, 5: None}
    assert sorted(t.leaf_ids.tolist()) == [3, 4, 5]
    assert t.descendant_leaves(t.index(1)).tolist() == [t.index(3), t.index(4)]


def test_identical_masks_are_siblings_not_nested():
    H, W = 20, 20
    m = rect(H, W, 2, 12, 2, 12)
    mc = MaskCandidates(np.stack([m, m, rect(H, W, 3, 6, 3, 6)]), np.array([7, 3, 9]))
    t = build_instance_tree(mc, frame=2, cfg=TreeConfig(min_area_px=1))
    par = {int(t.mask_ids[i]): (int(t.mask_ids[p]) if p >= 0 else None) for i, p in enumerate(t.parent)}
    # duplicates 3 and 7 are both roots; the small part goes under the lower id on the area tie
    assert par[3] is None and par[7] is None
    assert par[9] == 3


def test_empty_view_gives_empty_tree():
    t = build_instance_tree(MaskCandidates.empty(10, 10), frame=0)
    assert len(t.mask_ids) == 0 and t.is_leaf.shape == (0,)


def test_tiny_masks_are_dropped():
    H, W = 100, 100
    mc = MaskCandidates(np.stack([rect(H, W, 0, 1, 0, 1), rect(H, W, 10, 30, 10, 30)]), np.array([1, 2]))
    t = build_instance_tree(mc, 0, TreeConfig(min_area_px=2))
    assert t.mask_ids.tolist() == [2] and t.dropped_ids.tolist() == [1]


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(1, 70))
def test_overlaps_match_dense_and_tree_ignores_mask_order(seed, m):
    rng = np.random.default_rng(seed)
    H, W = 24, 32
    masks = np.zeros((m, H, W), bool)
    for i in range(m):
        r0, c0 = rng.integers(0, H - 2), rng.integers(0, W - 2)
        masks[i, r0 : rng.integers(r0 + 1, H), c0 : rng.integers(c0 + 1, W)] = True
    f = masks.reshape(m, -1).astype(np.int64)
    np.testing.assert_array_equal(mask_overlaps(masks), f @ f.T)
    ids = rng.permutation(np.arange(1, m + 1))
    t1 = build_instance_tree(MaskCandidates(masks, ids), 0, TreeConfig(min_area_px=1))
    perm = rng.permutation(m)
    t2 = build_instance_tree(MaskCandidates(masks[perm], ids[perm]), 0, TreeConfig(min_area_px=1))
    np.testing.assert_array_equal(t1.mask_ids, t2.mask_ids)
    np.testing.assert_array_equal(t1.parent, t2.parent)
    # a forest: following parents always ends at a root, and parents are strictly larger
    for i in range(len(t1.mask_ids)):
        p = t1.parent[i]
        if p >= 0:
            assert t1.areas[p] > t1.areas[i]


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 10_000), m=st.integers(0, 70), p=st.integers(1, 600))
def test_mask_codes_reconstruct_every_mask(seed, m, p):
    from clutt3r_core.segmentation.trees import mask_codes

    rng = np.random.default_rng(seed)
    # nested and random masks, so both few and many distinct codes occur
    flat = rng.random((m, p)) < rng.uniform(0.05, 0.9, size=(m, 1))
    label, bits = mask_codes(flat)
    assert label.shape == (p,) and bits.shape[1] == m
    np.testing.assert_array_equal(bits[label].T, flat)
    # codes are distinct: no two rows of bits are equal
    assert len({row.tobytes() for row in bits}) == len(bits)
