"""Mask crops on white (Sec. III-D)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.language.crops import mask_crops


def test_outside_the_mask_is_white_and_the_object_is_centred():
    rgb = np.zeros((60, 80, 3), np.uint8)
    rgb[...] = (10, 20, 30)
    m = np.zeros((2, 60, 80), bool)
    m[0, 10:30, 20:60] = True  # 20 x 40 box
    out = mask_crops(rgb, m, size=32, margin=0.0)
    assert out.shape == (2, 32, 32, 3)
    assert (out[1] == 255).all()  # empty mask: all white
    # letterboxed: the 40-wide box fills the width, rows above and below are white padding
    assert (out[0, 0] == 255).all() and (out[0, -1] == 255).all()
    assert (out[0, 16] == (10, 20, 30)).all()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_only_mask_colours_and_white_appear(seed):
    rng = np.random.default_rng(seed)
    rgb = np.zeros((30, 40, 3), np.uint8)
    rgb[...] = (200, 10, 10)
    rgb[rng.random((30, 40)) < 0.5] = (10, 200, 10)
    m = np.zeros((1, 30, 40), bool)
    r, c = rng.integers(0, 25), rng.integers(0, 35)
    m[0, r:r + 5, c:c + 5] = True
    rgb[m[0]] = (10, 10, 200)  # the object is blue, the background red/green
    out = mask_crops(rgb, m, size=16, margin=0.1, )
    # no background colour leaks in (resizing blends blue with white only)
    px = out[0].reshape(-1, 3).astype(int)
    assert (px[:, 0] == px[:, 1]).all()
