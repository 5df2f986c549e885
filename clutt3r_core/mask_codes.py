"""Mask-set codes: pixels factorised by the set of masks that contain them (issue 13).

Overlapping and nested mask candidates of a view form a few hundred distinct sets, so a code
image (the set of every pixel) and a small (sets x masks) bit table stand for the whole
(M, H, W) stack; ``scene.MaskCandidates`` stores them, and per-mask pixel sums (areas,
overlaps, histograms, hits per voxel) become sums over the sets, exact for counts.
"""

from __future__ import annotations

from typing import Iterable

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["encode_masks", "small_codes"]


def encode_masks(rows: Iterable[np.ndarray], n_pixels: int) -> tuple[np.ndarray, np.ndarray]:
    """Factorise pixels by the set of masks containing them, one mask at a time.

    ``rows``: the masks, each a bool array of ``n_pixels`` elements (any shape), consumed one
    by one (a loader can decode them one by one and never hold the stack).
    Returns (label (n_pixels,) uint8, uint16 or int64 (the narrowest for C) in 0..C-1, bits
    (C, M) bool): pixel p lies in mask m iff ``bits[label[p], m]``; sets are numbered in the
    order of their masks' bit patterns. Masks are packed 16 at a time into uint16 codes that are
    factorised by counting (no sort); the few hundred distinct sets of nested and overlapping
    masks then stand for the millions of pixels, and per-mask pixel sums become
    ``bits.T @ per_set_sums``, exact for integer counts. No mask gives one empty set
    (label all 0, bits (1, 0)).
    """
    p = int(n_pixels)
    label: np.ndarray | None = None
    bits = np.zeros((1, 0), bool)
    code = np.zeros(p, np.uint16)
    nb = 0  # masks in the current chunk of (at most) 16

    def fold() -> None:
        nonlocal label, bits
        present, clab = _compact(code, 1 << nb)
        cbits = ((present[:, None] >> np.arange(nb)) & 1).astype(bool)
        if label is None:
            label, bits = clab, cbits
            return
        n, k = len(bits), len(present)
        # the pair (set so far, this chunk's set) as one integer, in the narrowest type
        comb = label.astype(np.uint16 if n * k <= 1 << 16 else np.int64)
        comb *= k
        comb += clab
        used, label = _compact(comb, n * k)
        bits = np.concatenate([bits[used // k], cbits[used % k]], axis=1)

    for row in rows:
        m = np.ascontiguousarray(row, dtype=bool).reshape(-1)
        if m.shape[0] != p:
            raise SceneError(f"a mask has {m.shape[0]} pixels, expected {p}")
        # one masked OR per mask (half the time of shifting it into a scratch array and OR-ing that)
        np.bitwise_or(code, np.uint16(1 << nb), out=code, where=m)
        nb += 1
        if nb == 16:
            fold()
            code[:] = 0
            nb = 0
    if nb or label is None:
        fold()
    return label, bits


def _compact(x: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(used (U,) int64: the values of ``x`` (P,) ints in [0, n) that occur, ascending; rank (P,)
    of each element's value among them, in the narrowest unsigned type)."""
    if n <= 1 << 22:
        # every value that occurs starts a run of equal values (in pixel order), and a code
        # image has few runs (its values change only at mask boundaries): counting the runs'
        # values finds the same ones as counting every pixel. sample_seq4 1080p, 14 masks:
        # 1.7 ms, OpenCV's 16-bit histogram of every pixel 13.7 ms (issue 13).
        x = x.reshape(-1)
        run = np.empty(x.shape, bool)
        if x.size:
            run[0] = True
            np.not_equal(x[1:], x[:-1], out=run[1:])
        used = np.flatnonzero(np.bincount(x[run], minlength=n))
    else:  # very many possible values: sort instead of counting
        used, inv = np.unique(x, return_inverse=True)
        return used, inv.reshape(-1).astype(_rank_dtype(len(used)))
    lut = np.zeros(n, _rank_dtype(len(used)))
    lut[used] = np.arange(len(used))
    return used, np.take(lut, x, mode="clip")  # (x < n: clip never clips; it skips the bound checks)


def _rank_dtype(count: int) -> type:
    return np.uint8 if count <= 1 << 8 else np.uint16 if count <= 1 << 16 else np.int64


def small_codes(label: np.ndarray, n_sets: int, shape: tuple[int, int]) -> np.ndarray:
    """``label`` as an (H, W) code image in the narrowest type for ``n_sets`` sets (uint8, uint16, int32)."""
    dt = np.uint8 if n_sets <= 1 << 8 else np.uint16 if n_sets <= 1 << 16 else np.int32
    return label.astype(dt, copy=False).reshape(shape)
