"""``scene.MaskCandidates`` stores masks as a per-pixel mask-set code image (issue 13, 1080p memory):
every view of the masks (stack, one mask, areas, overlaps, a selection) equals the stack's."""

from __future__ import annotations

import pickle
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import MaskCandidates


def _stack(seed: int, m: int, h: int, w: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    out = np.zeros((m, h, w), bool)
    for i in range(m):  # boxes (nested and overlapping ones) and some noise masks
        if rng.random() < 0.7:
            y0, x0 = rng.integers(0, h), rng.integers(0, w)
            out[i, y0 : y0 + rng.integers(1, h + 1), x0 : x0 + rng.integers(1, w + 1)] = True
        else:
            out[i] = rng.random((h, w)) < rng.random()
    return out


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(0, 40), h=st.integers(1, 9), w=st.integers(1, 11))
def test_codes_stand_for_the_stack(seed, m, h, w):
    """Property: stack -> codes -> stack is the identity; areas and overlaps are the stack's
    counts; encoding one mask at a time gives the same codes as the whole stack."""
    stack = _stack(seed, m, h, w)
    mc = MaskCandidates(stack, np.arange(m) + 3)
    assert len(mc) == m and mc.shape == (h, w)
    assert mc.codes.dtype in (np.uint8, np.uint16) and mc.bits.shape[1] == m
    assert m == 0 or len(mc.bits) == len(np.unique(mc.bits, axis=0))  # each set once
    np.testing.assert_array_equal(mc.masks, stack)
    flat = stack.reshape(m, h * w).astype(np.int64)
    np.testing.assert_array_equal(mc.areas(), flat.sum(1))
    np.testing.assert_array_equal(mc.overlaps(), flat @ flat.T)
    for i in range(m):
        np.testing.assert_array_equal(mc.mask(i), stack[i])
    one = MaskCandidates.from_masks(iter(stack), np.arange(m) + 3, (h, w))
    np.testing.assert_array_equal(one.codes, mc.codes)
    np.testing.assert_array_equal(one.bits, mc.bits)
    idx = np.random.default_rng(seed).permutation(m)[: m // 2]
    sel = mc.select(idx)
    assert sel.codes is mc.codes  # the code image is shared, not copied
    np.testing.assert_array_equal(sel.ids, mc.ids[idx])
    np.testing.assert_array_equal(sel.stack(), stack[idx])
    np.testing.assert_array_equal(mc.stack(idx), stack[idx])
    np.testing.assert_array_equal(sel.overlaps(), flat[idx] @ flat[idx].T)


def test_the_stack_is_cached_read_only_and_not_pickled():
    stack = _stack(1, 5, 6, 7)
    mc = MaskCandidates(stack, np.arange(5), np.linspace(0, 1, 5))
    first = mc.masks
    assert mc.masks is first and not first.flags.writeable  # materialised once
    back = pickle.loads(pickle.dumps(mc))
    assert "_stack" not in back.__dict__
    np.testing.assert_array_equal(back.masks, stack)
    np.testing.assert_array_equal(back.scores, mc.scores)
    moved = replace(mc, ids=np.arange(5) + 10)  # dataclasses.replace goes through the codes
    np.testing.assert_array_equal(moved.masks, stack)
    np.testing.assert_array_equal(moved.ids, np.arange(5) + 10)
    np.testing.assert_array_equal(mc.select([4, 0]).scores, mc.scores[[4, 0]])


def test_bad_candidates_are_refused():
    with pytest.raises(SceneError, match="unique"):
        MaskCandidates(np.zeros((2, 3, 3), bool), [1, 1])
    with pytest.raises(SceneError, match="ids"):
        MaskCandidates(np.zeros((2, 3, 3), bool), [1])
    with pytest.raises(SceneError, match=r"\(M, H, W\)"):
        MaskCandidates(np.zeros((3, 3), bool), [1])
    with pytest.raises(SceneError, match="either"):
        MaskCandidates(ids=[1])
    with pytest.raises(SceneError, match="lie in"):
        MaskCandidates(ids=[1], codes=np.full((2, 2), 2, np.uint8), bits=np.ones((2, 1), bool))
    with pytest.raises(SceneError, match="scores"):
        MaskCandidates(np.zeros((2, 3, 3), bool), [1, 2], [0.5])
    e = MaskCandidates.empty(4, 5)
    assert len(e) == 0 and e.shape == (4, 5) and e.masks.shape == (0, 4, 5) and e.areas().shape == (0,)


def test_view_depth_is_copied_unless_frozen_with_nan_holes():
    from clutt3r_core.scene import Camera, View

    cam = Camera(np.array([[10.0, 0, 2], [0, 10.0, 1.5], [0, 0, 1]]), 4, 3, np.eye(4))
    rgb = np.zeros((3, 4, 3), np.uint8)
    d = np.full((3, 4), 0.5, np.float32)
    d[0, 0], d[1, 1] = 0.0, -1.0
    v = View(0, rgb, cam, d)
    assert v.depth is not d and d[0, 0] == 0.0 and d.flags.writeable  # the caller's array is untouched
    assert np.isnan(v.depth[0, 0]) and np.isnan(v.depth[1, 1]) and not v.depth.flags.writeable
    frozen = v.depth.copy()
    frozen.setflags(write=False)
    assert View(0, rgb, cam, frozen).depth is frozen  # a loader's frozen map with NaN holes: no copy
    bad = d.copy()
    bad.setflags(write=False)  # frozen but with a 0 and a negative: still made NaN, in a copy
    got = View(0, rgb, cam, bad).depth
    assert got is not bad and np.isnan(got[0, 0]) and np.isnan(got[1, 1]) and bad[0, 0] == 0.0
    inf = frozen.copy()
    inf[2, 2] = np.inf
    inf.setflags(write=False)
    with pytest.raises(SceneError, match="inf"):
        View(0, rgb, cam, inf)
