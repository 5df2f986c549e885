"""``MaskCandidates.areas`` on every stack size, the empty one included (a post-interaction view
whose detector found nothing has 0 masks; ``reshape(0, -1)`` used to raise there)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.scene import MaskCandidates


def test_areas_of_an_empty_stack():
    a = MaskCandidates.empty(4, 5).areas()
    assert a.shape == (0,) and a.dtype == np.int64


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 4), st.integers(1, 6), st.integers(1, 6), st.integers(0, 2**31 - 1))
def test_areas_count_each_masks_pixels(m, h, w, seed):
    masks = np.random.default_rng(seed).random((m, h, w)) < 0.4
    a = MaskCandidates(masks, np.arange(1, m + 1, dtype=np.int32)).areas()
    assert a.shape == (m,) and a.dtype == np.int64
    assert a.tolist() == [int(x.sum()) for x in masks]
