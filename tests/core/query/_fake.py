"""A tiny language backend for wiring tests: grounds through three colour 'classes'.

It tests the plumbing (evidence, cache, CLI), not language understanding."""

from __future__ import annotations

import json
import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from clutt3r_core.language.base import MaskEvidence
from clutt3r_core.language.colors import COLOR_WORDS, color_shares

LABELS = ("red thing", "green thing", "blue thing")


class FakeGrounder:
    name = "fake-ground"
    dim = 3

    def __init__(self, version: str = "1") -> None:
        self.version = version
        self.calls = 0

    @property
    def labels(self):
        return LABELS

    def mask_evidence(self, rgb, masks):
        self.calls += 1
        s = color_shares(rgb, masks)
        idx = [COLOR_WORDS.index(w) for w in ("red", "green", "blue")]
        p = s[:, idx] + 0.05
        p /= p.sum(axis=1, keepdims=True)
        f = s[:, idx] + 1e-3
        return MaskEvidence(f / np.linalg.norm(f, axis=1, keepdims=True), np.log(p).astype(np.float32))

    def embed_masks(self, rgb, masks):
        return self.mask_evidence(rgb, masks).features

    def embed_text(self, texts):
        out = np.full((len(texts), 3), 0.1, np.float32)
        for i, t in enumerate(texts):
            for j, lab in enumerate(LABELS):
                if lab.split()[0] in t.lower():
                    out[i, j] = 1.0
        return out / np.linalg.norm(out, axis=1, keepdims=True)

    def label_embeddings(self):
        return np.eye(3, dtype=np.float32)


def copy_run(run: Path, scene_root: Path, dst: Path) -> Path:
    """A copy of the run folder ``run`` at ``dst`` whose ``run.json`` still records the scene
    ``scene_root / "scene"`` (absolute), so the copy finds its images."""
    shutil.copytree(run, dst)
    info = json.loads((dst / "run.json").read_text())
    info["scene"] = str((scene_root / "scene").resolve())
    (dst / "run.json").write_text(json.dumps(info))
    return dst


@contextmanager
def fake_ground_registered():
    """``FakeGrounder`` registered as the text embedder "fake-ground" for the block."""
    from clutt3r_core.registry import REGISTRY

    REGISTRY.register("text_embedder", "fake-ground", FakeGrounder)
    try:
        yield
    finally:
        REGISTRY.unregister("text_embedder", "fake-ground")
