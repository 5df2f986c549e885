"""Tests for clutt3r_core.graph_ops (connected components and index ranges in numpy)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(0, 300), m=st.integers(0, 900),
       shape=st.sampled_from(["random", "chains", "reversed_chain"]))
def test_components_equal_scipy_connected_components(seed, n, m, shape):
    """Issue 13: the super-voxels' own connected components (scipy.sparse.csgraph is not
    imported by the segment command) are scipy's labels, numbering included: components in
    the order of their smallest vertex; also on long chains in scrambled or reversed order
    (the slowest case for min-label hooking), repeated edges and self-loops."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    from clutt3r_core.graph_ops import connected_components as _components

    rng = np.random.default_rng(seed)
    if shape == "random" or n < 2:
        src = rng.integers(0, max(n, 1), m) if n else np.zeros(0, np.int64)
        dst = rng.integers(0, max(n, 1), m) if n else np.zeros(0, np.int64)
    else:
        perm = rng.permutation(n) if shape == "chains" else np.arange(n)[::-1]
        cut = rng.random(n - 1) < 0.05  # a few chains
        src, dst = perm[:-1][~cut], perm[1:][~cut]
        if rng.random() < 0.5:
            src, dst = dst, src
    src, dst = src.astype(np.int32), dst.astype(np.int32)
    got = _components(n, src, dst)
    g = coo_matrix((np.ones(len(src)), (src, dst)), shape=(n, n)).tocsr()
    want = connected_components(g, directed=False)[1]
    assert got.dtype == np.int32
    np.testing.assert_array_equal(got, want)


def test_ranges_concatenate_index_ranges():
    from clutt3r_core.graph_ops import concat_ranges as _ranges

    starts, ends = np.array([3, 0, 7, 7, 2]), np.array([5, 0, 7, 9, 3])
    np.testing.assert_array_equal(_ranges(starts, ends), [3, 4, 7, 8, 2])
    assert _ranges(np.zeros(0, np.int64), np.zeros(0, np.int64)).shape == (0,)
