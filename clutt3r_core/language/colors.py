"""Colour words: which share of a mask's pixels has each basic colour, and which colour
words a query names.

Eleven basic colour terms (Berlin and Kay's universal set: black, white, red, green,
yellow, blue, brown, orange, pink, purple, grey). A pixel is named by rules on its HSV
value (OpenCV full-range hue 0-255), evaluated once per quantised RGB colour (32 levels
per channel) into a lookup table, so naming a mask is a table gather plus a bincount.

The rules are ours, written for shaded, lit objects: value below ``DARK`` is black, low
saturation is white / grey by value, brown is a dark orange-red, pink a light unsaturated
red-magenta. They are checked in ``tests/core/language/test_colors.py`` on reference
colours (the generator's object colours and their shading).
"""

from __future__ import annotations

import re
from functools import lru_cache

import numpy as np

__all__ = ["COLOR_VERSION", "COLOR_WORDS", "SYNONYMS", "color_shares", "color_name_of", "colors_in_text", "strip_colors"]

COLOR_VERSION = "2"
"""Bump when the naming rules change: cached colour shares of older rules are recomputed."""

COLOR_WORDS: tuple[str, ...] = (
    "red", "orange", "yellow", "green", "blue", "purple", "pink", "brown", "white", "grey", "black",
)
"""Index order of the colour-share vectors."""

SYNONYMS: dict[str, str] = {
    "gray": "grey", "silver": "grey", "violet": "purple", "magenta": "pink", "cyan": "blue",
    "teal": "green", "navy": "blue", "golden": "yellow", "gold": "yellow", "beige": "brown",
    "tan": "brown", "wooden": "brown", "crimson": "red", "maroon": "red", "turquoise": "blue",
}
"""Other words users type for the same basic colours."""

_Q = 8  # quantisation step of the lookup table (256 / 8 = 32 levels per channel)
DARK = 50
"""Value (0-255) below which a pixel is black whatever its hue (shadows, black plastic)."""
GREY_SAT = 45
"""Saturation (0-255) below which a pixel has no reliable hue: white, grey or black by value."""


def _name_hsv(h: np.ndarray, s: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Colour-word index per pixel from OpenCV full-range HSV (all 0-255 ints)."""
    idx = {w: i for i, w in enumerate(COLOR_WORDS)}
    out = np.full(h.shape, idx["grey"], np.int8)
    deg = h.astype(np.float64) * (360.0 / 256.0)
    chroma = s >= GREY_SAT
    # hue families (degrees)
    red = (deg < 14) | (deg >= 330)
    orange = (deg >= 14) & (deg < 40)
    yellow = (deg >= 40) & (deg < 70)
    green = (deg >= 70) & (deg < 170)
    blue = (deg >= 170) & (deg < 260)
    purple = (deg >= 260) & (deg < 300)
    magenta = (deg >= 300) & (deg < 330)
    out[chroma & red] = idx["red"]
    out[chroma & orange] = idx["orange"]
    out[chroma & yellow] = idx["yellow"]
    out[chroma & green] = idx["green"]
    out[chroma & blue] = idx["blue"]
    out[chroma & purple] = idx["purple"]
    out[chroma & magenta] = idx["pink"]
    # dark, warm, moderately saturated: brown (wood, cardboard, chocolate)
    # a shaded red object stays red (a red mug in a dim scene); only a dull dark red is brown
    brown = chroma & ((orange & (v < 150)) | (red & (v < 150) & (s < 130)))
    brown |= chroma & yellow & (v < 100)  # shaded yellow stays yellow down to mid value
    brown |= chroma & orange & (s < 130) & (v < 215)  # wood, cardboard: light but unsaturated
    out[brown] = idx["brown"]
    # light, weakly saturated red/magenta: pink
    pink = chroma & (red | magenta) & (s < 140) & (v > 170)
    out[pink] = idx["pink"]
    # a dark purple-red with low value reads as purple (plum) rather than brown
    out[chroma & magenta & (v < 150)] = idx["purple"]
    out[~chroma & (v >= 185)] = idx["white"]
    out[~chroma & (v < 185)] = idx["grey"]
    out[v < DARK] = idx["black"]
    return out


@lru_cache(maxsize=1)
def _lut() -> np.ndarray:
    import cv2

    levels = np.arange(_Q // 2, 256, _Q, dtype=np.uint8)  # bin centres
    r, g, b = np.meshgrid(levels, levels, levels, indexing="ij")
    rgb = np.stack([r, g, b], -1).reshape(-1, 1, 3)
    hsv = cv2.cvtColor(rgb, cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(np.int32)
    return _name_hsv(hsv[:, 0], hsv[:, 1], hsv[:, 2])


def _pixel_names(rgb: np.ndarray) -> np.ndarray:
    q = (rgb.astype(np.int32) // _Q)
    n = 256 // _Q
    return _lut()[(q[..., 0] * n + q[..., 1]) * n + q[..., 2]]


def color_name_of(rgb: tuple[int, int, int] | np.ndarray) -> str:
    """The colour word of one RGB colour (0-255)."""
    return COLOR_WORDS[int(_pixel_names(np.asarray(rgb, np.uint8).reshape(1, 3))[0])]


def color_shares(rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """(M, C) float32: share of each mask's pixels named by each of ``COLOR_WORDS``.

    rgb (H, W, 3) uint8, masks (M, H, W) bool. Rows sum to 1 (0 for an empty mask).
    """
    m = masks.shape[0]
    c = len(COLOR_WORDS)
    out = np.zeros((m, c), np.float32)
    if m == 0:
        return out
    names = _pixel_names(rgb).reshape(-1).astype(np.int64)
    flat = masks.reshape(m, -1)
    for i in range(m):
        sel = names[flat[i]]
        if sel.size:
            out[i] = np.bincount(sel, minlength=c)[:c] / sel.size
    return out


_WORD = re.compile(r"[a-z]+")


def colors_in_text(text: str) -> tuple[str, ...]:
    """Basic colour words named in ``text`` (synonyms mapped), in order, without repeats."""
    out: list[str] = []
    for w in _WORD.findall(text.lower()):
        w = SYNONYMS.get(w, w)
        if w in COLOR_WORDS and w not in out:
            out.append(w)
    return tuple(out)


def strip_colors(text: str) -> str:
    """``text`` without its colour words (the object-name part of a query)."""
    keep = [w for w in re.findall(r"[A-Za-z0-9'-]+", text)
            if SYNONYMS.get(w.lower(), w.lower()) not in COLOR_WORDS]
    return " ".join(keep)
