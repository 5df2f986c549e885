"""Colour words: naming of reference colours, shares per mask, parsing of queries."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.language.colors import COLOR_WORDS, color_name_of, color_shares, colors_in_text, strip_colors


@pytest.mark.parametrize(
    "rgb,word",
    [
        ((245, 200, 20), "yellow"),   # mustard bottle
        ((232, 202, 52), "yellow"),   # banana
        ((175, 35, 30), "red"),       # apple
        ((240, 130, 20), "orange"),   # orange
        ((60, 160, 80), "green"),     # cup
        ((40, 100, 200), "blue"),     # toy brick
        ((95, 30, 75), "purple"),     # plum
        ((125, 75, 40), "brown"),     # pudding box
        ((195, 155, 105), "brown"),   # wood block
        ((236, 230, 218), "white"),   # baseball
        ((150, 150, 158), "grey"),    # wrench
        ((30, 30, 30), "black"),      # marker
        ((250, 170, 200), "pink"),
    ],
)
def test_reference_colours(rgb, word):
    assert color_name_of(rgb) == word


@pytest.mark.parametrize("rgb,word", [((245, 200, 20), "yellow"), ((60, 160, 80), "green"), ((40, 100, 200), "blue")])
def test_shaded_colours_keep_their_name(rgb, word):
    # a lit object's far side is darker: 60 % of the colour still has its name
    assert color_name_of(tuple(int(0.6 * c) for c in rgb)) == word


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_shares_are_distributions(seed):
    rng = np.random.default_rng(seed)
    rgb = rng.integers(0, 256, (12, 10, 3), dtype=np.uint8)
    masks = rng.random((4, 12, 10)) < rng.random((4, 1, 1))
    s = color_shares(rgb, masks)
    assert s.shape == (4, len(COLOR_WORDS))
    for m, row in zip(masks, s):
        assert row.min() >= 0
        assert row.sum() == pytest.approx(1.0 if m.any() else 0.0, abs=1e-6)


def test_share_counts_only_mask_pixels():
    rgb = np.zeros((4, 4, 3), np.uint8)
    rgb[:, :2] = (240, 130, 20)  # orange left half, black right half
    m = np.zeros((2, 4, 4), bool)
    m[0, :, :2] = True
    m[1, :, 1:3] = True
    s = color_shares(rgb, m)
    assert s[0, COLOR_WORDS.index("orange")] == pytest.approx(1.0)
    assert s[1, COLOR_WORDS.index("orange")] == pytest.approx(0.5)
    assert s[1, COLOR_WORDS.index("black")] == pytest.approx(0.5)


def test_query_colour_words():
    assert colors_in_text("the Yellow mustard bottle") == ("yellow",)
    assert colors_in_text("a gray and silver can, red label") == ("grey", "red")
    assert colors_in_text("mustard bottle") == ()
    assert strip_colors("the yellow mustard bottle") == "the mustard bottle"
