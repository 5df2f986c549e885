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
        the pipeline passes one), any other gets the stack. One with a true ``beside_fusion``
        attribute is called on a second thread while the point cloud is fused (it must be
        thread-safe and light on memory)."""
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
    beside_fusion: ClassVar[bool] = True
    """Cheap, small and thread-safe (numpy and OpenCV, which release the GIL): the pipeline
    embeds the views on a second thread while it fuses the point cloud (issue 13, whole-command
    time). An embedder without this attribute runs after the fusion, as before."""

    @property
    def dim(self) -> int:
        return (self.hue_bins + 1) * self.sat_bins + self.val_bins

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray | MaskCandidates) -> np.ndarray:
        import cv2

        m = len(masks)
        out = np.zeros((m, self.dim), np.float32)
        if m == 0:
            return out
        if not isinstance(masks, MaskCandidates):
            masks = MaskCandidates(np.asarray(masks, bool), np.arange(m))
        hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV_FULL)
        h, s, v = cv2.split(hsv)
        del hsv
        # Per-pixel bins as 8-bit (16-bit for wide histograms) planes through lookup tables
        # over the 8-bit channels: the same formulas, evaluated once per possible value.
        a = np.arange(256)
        nj, nv = (self.hue_bins + 1) * self.sat_bins, self.val_bins
        codes, bits = masks.codes, masks.bits
        c = len(bits)
        # one depth for every plane (calcHist wants that): 8-bit, 16-bit, or float32 (exact:
        # fewer than 2^24 sets and bins)
        top = max(nj, nv, c)
        dt = np.uint8 if top <= 1 << 8 else np.uint16 if top <= 1 << 16 else np.float32
        joint = cv2.LUT(h, (a * self.hue_bins // 256 * self.sat_bins).astype(dt))  # hue bin * sat_bins
        grey = cv2.LUT(s, (a < self.min_saturation).astype(np.uint8)).view(bool)
        np.copyto(joint, dt(self.hue_bins * self.sat_bins), where=grey)  # the grey row
        joint += cv2.LUT(s, (a * self.sat_bins // 256).astype(dt))
        vq = cv2.LUT(v, (a * self.val_bins // 256).astype(dt))
        # Histograms per distinct set of containing masks (the candidates' code image: a
        # few hundred sets instead of a gather over every mask pixel), as 2D histograms of
        # (set, bin), summed into each mask by bits.T @ per-set histograms. Counts are
        # integers (exact in calcHist's float32 below 2^24 per bin), so the result is
        # exactly the per-mask count.
        codes = codes.astype(dt, copy=False)
        per_code = np.concatenate([
            cv2.calcHist([codes, joint], [0, 1], None, [c, nj], [0, c, 0, nj]),
            cv2.calcHist([codes, vq], [0, 1], None, [c, nv], [0, c, 0, nv]),
        ], axis=1).astype(np.float64)
        hist = bits.T.astype(np.float64) @ per_code
        hist = np.sqrt(hist)
        norm = np.linalg.norm(hist, axis=1, keepdims=True)
        np.divide(hist, norm, out=hist, where=norm > 0)
        return hist.astype(np.float32)

