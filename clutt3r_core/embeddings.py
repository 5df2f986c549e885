"""Mask embedders: the pluggable source of S_semantic (Sec. III-B.2, eq. 3).

The paper embeds each mask with Duoduo CLIP. Backends sit behind the small
``MaskEmbedder`` / ``TextEmbedder`` protocols in the core's one registry
(``clutt3r_core/registry.py``); heavy imports happen inside factories, and a missing
optional package fails at construction naming the extra to install.

Built in: ``appearance-hsv``, a documented appearance descriptor (no language
model): a joint hue x saturation histogram plus a value histogram of the masked
pixels, square-rooted and L2-normalised, so the cosine of two descriptors is the
Bhattacharyya coefficient of the colour distributions. Results computed with it
are labelled with its name (``Segmentation.embedder``); it cannot embed text.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, ClassVar, Protocol, runtime_checkable

import numpy as np

from clutt3r_core.scene import MaskCandidates

__all__ = [
    "MaskEmbedder",
    "TextEmbedder",
    "register_embedder",
    "create_embedder",
    "available_embedders",
    "has_text",
    "AppearanceEmbedder",
]


@runtime_checkable
class MaskEmbedder(Protocol):
    """Embeds image regions into a unit-norm space (registry kind ``mask_embedder``)."""

    name: str
    dim: int

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
        """rgb (H, W, 3) uint8, masks (M, H, W) bool -> (M, dim) float32, rows unit norm
        (a zero row for an empty mask). An embedder with a true ``accepts_candidates``
        attribute also takes a ``scene.MaskCandidates`` (compact: no (M, H, W) stack is made;
        the pipeline passes one), any other gets the stack."""
        ...


@runtime_checkable
class TextEmbedder(Protocol):
    """Embeds text into the same space as a mask embedder of the same name (registry kind
    ``text_embedder``); a language backend registers under both kinds."""

    name: str
    dim: int

    def embed_text(self, texts: list[str]) -> np.ndarray:
        """-> (T, dim) float32 unit rows."""
        ...


def register_embedder(name: str, factory: Callable[..., MaskEmbedder] | str, *, text: bool = False, **kw) -> None:
    """Register a mask embedder (and, with ``text=True``, the same factory as a text embedder)."""
    from clutt3r_core.registry import register_backend

    register_backend("mask_embedder", name, factory, **kw)
    if text:
        register_backend("text_embedder", name, factory, **kw)


def available_embedders() -> tuple[str, ...]:
    from clutt3r_core.registry import backend_names

    return tuple(sorted(backend_names("mask_embedder")))


def create_embedder(name: str, **kwargs) -> MaskEmbedder:
    from clutt3r_core.registry import create_backend

    return create_backend("mask_embedder", name, **kwargs)


def has_text(embedder: object) -> bool:
    """Whether an embedder can also embed text (implements ``TextEmbedder``)."""
    return isinstance(embedder, TextEmbedder)


@dataclass(frozen=True)
class AppearanceEmbedder:
    """Colour-distribution descriptor (ours; a stand-in for Duoduo CLIP, named as such in results)."""

    hue_bins: int = 16
    sat_bins: int = 4
    val_bins: int = 4
    min_saturation: int = 40
    """Pixels with saturation below this (0-255) are counted in a separate grey row, whose hue is noise."""
    name: str = "appearance-hsv"
    accepts_candidates: ClassVar[bool] = True
    """``embed_masks`` also takes ``scene.MaskCandidates`` (their code image is the factorisation
    the histograms need; issue 13, 1080p memory)."""

    @property
    def dim(self) -> int:
        return (self.hue_bins + 1) * self.sat_bins + self.val_bins

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray | MaskCandidates) -> np.ndarray:
        import cv2

        m = len(masks)
        out = np.zeros((m, self.dim), np.float32)
        if m == 0:
            return out
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3)
        # Bin indices through lookup tables over the 8-bit channels (same formulas,
        # evaluated once per possible value instead of once per pixel).
        hv, sv = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")
        hb = np.where(sv >= self.min_saturation, hv * self.hue_bins // 256, self.hue_bins)
        lut_joint = (hb * self.sat_bins + sv * self.sat_bins // 256).astype(np.int32).reshape(-1)
        lut_v = ((self.hue_bins + 1) * self.sat_bins + np.arange(256) * self.val_bins // 256).astype(np.int32)
        joint = lut_joint[(hsv[:, 0].astype(np.int32) << 8) | hsv[:, 1]]
        vb = lut_v[hsv[:, 2]]
        del hsv
        d = self.dim
        # Histograms per distinct set of containing masks (a few hundred codes instead of
        # a gather over every mask pixel), summed into each mask by bits.T @ per-code
        # histograms. Counts are integers, so the result is exactly the per-mask count.
        if isinstance(masks, MaskCandidates):
            label, bits = masks.codes.reshape(-1), masks.bits
        else:
            from clutt3r_core.segmentation.trees import mask_codes

            label, bits = mask_codes(np.asarray(masks).reshape(m, -1))
        c = len(bits)
        # one reused int32 key array (int64 temporaries were 3 x 16 MiB per 1080p view)
        key = label.astype(np.int32 if c * d < 2**31 else np.int64)
        del label
        key *= d
        key += joint
        per_code = np.bincount(key, minlength=c * d).astype(np.float64)
        key -= joint
        key += vb
        per_code += np.bincount(key, minlength=c * d)
        hist = bits.T.astype(np.float64) @ per_code.reshape(c, d)
        hist = hist.reshape(m, d)
        hist = np.sqrt(hist)
        norm = np.linalg.norm(hist, axis=1, keepdims=True)
        np.divide(hist, norm, out=hist, where=norm > 0)
        return hist.astype(np.float32)

