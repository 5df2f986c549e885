"""Mask embedders: the pluggable source of S_semantic (Sec. III-B.2, eq. 3).

The paper embeds each mask with Duoduo CLIP. Backends sit behind the small
``MaskEmbedder`` protocol and a registry; heavy imports happen inside factories,
and a missing optional package fails at construction naming the extra to install.

Built in: ``appearance-hsv``, a documented appearance descriptor (no language
model): a joint hue x saturation histogram plus a value histogram of the masked
pixels, square-rooted and L2-normalised, so the cosine of two descriptors is the
Bhattacharyya coefficient of the colour distributions. Results computed with it
are labelled with its name (``Segmentation.embedder``); it cannot embed text.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Protocol, runtime_checkable

import numpy as np

from clutt3r_core.errors import Clutt3rError

__all__ = ["MaskEmbedder", "register_embedder", "create_embedder", "available_embedders", "AppearanceEmbedder"]


@runtime_checkable
class MaskEmbedder(Protocol):
    """Embeds image regions (and, for language backends, text) into one unit-norm space."""

    name: str
    dim: int

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """rgb (H, W, 3) uint8, masks (M, H, W) bool -> (M, dim) float32, rows unit norm
        (a zero row for an empty mask)."""
        ...

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """-> (T, dim) float32 unit rows. Raises NotImplementedError for image-only backends."""
        ...


_REGISTRY: dict[str, Callable[..., MaskEmbedder]] = {}


def register_embedder(name: str, factory: Callable[..., MaskEmbedder]) -> None:
    _REGISTRY[name] = factory


def available_embedders() -> tuple[str, ...]:
    return tuple(sorted(_REGISTRY))


def create_embedder(name: str, **kwargs) -> MaskEmbedder:
    if name not in _REGISTRY:
        raise Clutt3rError(f"unknown embedder '{name}'; available: {', '.join(available_embedders())}")
    return _REGISTRY[name](**kwargs)


@dataclass(frozen=True)
class AppearanceEmbedder:
    """Colour-distribution descriptor (ours; a stand-in for Duoduo CLIP, named as such in results)."""

    hue_bins: int = 16
    sat_bins: int = 4
    val_bins: int = 4
    min_saturation: int = 40
    """Pixels with saturation below this (0-255) are counted in a separate grey row, whose hue is noise."""
    name: str = "appearance-hsv"

    @property
    def dim(self) -> int:
        return (self.hue_bins + 1) * self.sat_bins + self.val_bins

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
        import cv2

        m = masks.shape[0]
        out = np.zeros((m, self.dim), np.float32)
        if m == 0:
            return out
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(np.int64)
        h, s, v = hsv[:, 0], hsv[:, 1], hsv[:, 2]
        hb = np.where(s >= self.min_saturation, h * self.hue_bins // 256, self.hue_bins)
        sb = s * self.sat_bins // 256
        joint = hb * self.sat_bins + sb
        vb = (self.hue_bins + 1) * self.sat_bins + v * self.val_bins // 256
        flat = masks.reshape(m, -1)
        mi, pix = np.nonzero(flat)
        d = self.dim
        hist = np.bincount(mi * d + joint[pix], minlength=m * d).astype(np.float64)
        hist += np.bincount(mi * d + vb[pix], minlength=m * d)
        hist = hist.reshape(m, d)
        hist = np.sqrt(hist)
        norm = np.linalg.norm(hist, axis=1, keepdims=True)
        np.divide(hist, norm, out=hist, where=norm > 0)
        return hist.astype(np.float32)

    def embed_text(self, texts: list[str]) -> np.ndarray:
        raise NotImplementedError("the appearance-hsv embedder has no text encoder; use a language backend")


register_embedder("appearance-hsv", AppearanceEmbedder)
