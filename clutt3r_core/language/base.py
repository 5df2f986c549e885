"""What a language backend gives the query stage (``clutt3r_core.query``).

A language backend is registered under both registry kinds ``mask_embedder`` and
``text_embedder`` (one factory). Besides those protocols it implements ``Grounder``:

* ``mask_evidence(rgb, masks)`` -> ``MaskEvidence``: per mask, image features (for
  S_semantic) and a *grounding* vector;
* ``embed_text(texts)``: the text side;
* ``labels``: ``None`` when grounding vectors and text embeddings share one space
  (CLIP-like: a query's score is the cosine of the two), or the names of the grounding
  vector's dimensions when the backend grounds through a closed label set (the ImageNet
  backend: grounding rows are log-probabilities over 1000 class names, and a query is
  compared with the label names' text embeddings, ``label_embeddings()``).

Both cases make a query's raw score linear in the instance's aggregated grounding vector,
so the multi-view aggregation and the cache are the same for every backend.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["MaskEvidence", "Grounder"]


@dataclass(frozen=True, eq=False)
class MaskEvidence:
    """Per-mask evidence of one view.

    Attributes:
        features: (M, D) float32 unit rows, image features (S_semantic, eq. 3); zero row for
            an empty mask.
        grounding: (M, G) float32: log-probabilities over ``Grounder.labels`` (label mode) or
            unit embeddings in the text space (shared-space mode).
    """

    features: np.ndarray
    grounding: np.ndarray

    def __post_init__(self) -> None:
        if self.features.ndim != 2 or self.grounding.ndim != 2 or len(self.features) != len(self.grounding):
            raise SceneError(
                f"MaskEvidence: features (M,D) and grounding (M,G) must agree, got "
                f"{self.features.shape} and {self.grounding.shape}"
            )


@runtime_checkable
class Grounder(Protocol):
    """A backend that can tell which masks a phrase names (see module docstring)."""

    name: str
    version: str
    dim: int

    @property
    def labels(self) -> tuple[str, ...] | None: ...

    def mask_evidence(self, rgb: np.ndarray, masks: np.ndarray) -> MaskEvidence: ...

    def embed_text(self, texts: list[str]) -> np.ndarray: ...

    def label_embeddings(self) -> np.ndarray:
        """(L, Dt) float32 unit text embeddings of ``labels`` (label mode only)."""
        ...
