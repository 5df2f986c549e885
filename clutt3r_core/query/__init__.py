"""Text queries on instances (Sec. III-D): which instance does a phrase name?"""

from __future__ import annotations

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["instance_text_scores"]


def instance_text_scores(seg, text_embedding: np.ndarray) -> np.ndarray:
    """(I,) float32: for each instance of ``seg`` (a ``Segmentation``), the best cosine between
    the text embedding and the embeddings of the instance's masks (``seg.trace.embeddings``)."""
    t = np.asarray(text_embedding, np.float32).reshape(-1)
    e = seg.trace.embeddings
    if e.shape[1] != t.shape[0]:
        raise SceneError(f"text embedding has {t.shape[0]} dims but the run's mask embeddings have {e.shape[1]}")
    cos = e @ (t / max(float(np.linalg.norm(t)), 1e-12))
    out = np.full(seg.num_instances, -1.0, np.float32)
    for k in range(seg.num_instances):
        nodes = list(seg.instance_nodes(k))
        if nodes:
            out[k] = cos[nodes].max()
    return out
