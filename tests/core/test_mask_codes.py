"""``mask_codes.encode_masks``: pixels factorised by the set of masks containing them (issue 13)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.mask_codes import encode_masks, small_codes


def test_encode_masks_labels_and_bits():
    a = np.array([[1, 1, 0, 0]], bool)
    b = np.array([[0, 1, 1, 0]], bool)
    label, bits = encode_masks(iter([a, b]), 4)
    # pixel p is in mask m iff bits[label[p], m]
    np.testing.assert_array_equal(bits[label], np.stack([a[0], b[0]], axis=1))
    label0, bits0 = encode_masks(iter([]), 5)
    assert bits0.shape == (1, 0) and not label0.any()
    with pytest.raises(SceneError, match="pixels"):
        encode_masks(iter([np.ones(3, bool)]), 4)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), m=st.integers(0, 50), p=st.integers(1, 300))
def test_every_pixel_gets_exactly_its_masks(seed, m, p):
    """Property: bits[label] is the (P, M) membership matrix; sets are distinct; labels use
    0..C-1 and the narrowest type; across the 16-mask chunks too (m up to 50)."""
    rng = np.random.default_rng(seed)
    masks = rng.random((m, p)) < rng.random()
    label, bits = encode_masks(iter(masks), p)
    np.testing.assert_array_equal(bits[label], masks.T)
    assert bits.shape[1] == m and set(np.unique(label)) == set(range(len(bits)))
    assert m == 0 or len(np.unique(bits, axis=0)) == len(bits)
    assert label.dtype == (np.uint8 if len(bits) <= 256 else np.uint16)
    codes = small_codes(label, len(bits), (1, p))
    assert codes.shape == (1, p) and codes.dtype.itemsize <= 2



@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), p=st.integers(0, 400), n=st.sampled_from([1, 2, 300, 1 << 16, 1 << 20]),
       runs=st.booleans(), dtype=st.sampled_from([np.uint8, np.uint16, np.int64]))
def test_compact_finds_the_values_that_occur_and_ranks_them(seed, p, n, runs, dtype):
    """Property: ``_compact`` (which reads only the first value of every run of equal values,
    issue 13) gives np.unique's values and inverse, on run-like (code image) and noisy input."""
    from clutt3r_core.mask_codes import _compact

    n = min(n, np.iinfo(dtype).max + 1)
    rng = np.random.default_rng(seed)
    x = rng.integers(0, n, p)
    if runs:  # long runs of few values, like a code image
        x = np.repeat(rng.integers(0, n, max(p // 20, 1)), 20)[:p]
    x = x.astype(dtype)
    used, rank = _compact(x, n)
    want, inv = np.unique(x, return_inverse=True)
    np.testing.assert_array_equal(used, want)
    np.testing.assert_array_equal(rank, inv.reshape(-1))
    assert rank.dtype == (np.uint8 if len(used) <= 256 else np.uint16)
