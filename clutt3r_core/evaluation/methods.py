"""Benchmark methods behind one protocol (registry kind ``bench_method``).

Every method maps a scene (fused the same way) to a ``Prediction``; the built-in ones are
Clutt3R's presets, the two baselines, and the leave-one-out ablation of our additions over the
paper (``ABLATION_METHODS``: ``ours-no-<key>`` = ours with one addition off, ``paper-with-<key>``
= the paper preset with one addition on; the additions are ``config.ADDITIONS``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from clutt3r_core.baselines.common import Prediction
from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Scene

__all__ = ["BenchMethod", "make_method", "PRESET_OF", "ABLATION_METHODS", "method_config"]

PRESET_OF = {"ours": "default", "paper": "paper", "no-spatial": "no-spatial", "no-substitution": "no-substitution",
             "ours-noisy-depth": "noisy-depth"}
"""Benchmark method name -> segmentation preset."""


def _ablations() -> dict[str, str]:
    from clutt3r_core.config import ADDITIONS

    out = {f"ours-no-{a.key}": f"ours without: {a.what}" for a in ADDITIONS}
    out.update({f"paper-with-{a.key}": f"paper with: {a.what}" for a in ADDITIONS})
    return out


ABLATION_METHODS: dict[str, str] = _ablations()
"""Leave-one-out ablation method name -> description (``clutt3r bench --ablation``)."""


def method_config(name: str):
    """The ``SegmentConfig`` of a Clutt3R method (preset or ablation), None for a baseline."""
    from clutt3r_core.config import PRESETS, ours_without, paper_with

    if name in PRESET_OF:
        return PRESETS[PRESET_OF[name]]
    if name.startswith("ours-no-") and name in ABLATION_METHODS:
        return ours_without(name[len("ours-no-"):])
    if name.startswith("paper-with-") and name in ABLATION_METHODS:
        return paper_with(name[len("paper-with-"):])
    return None


@runtime_checkable
class BenchMethod(Protocol):
    name: str

    def predict(self, scene: Scene) -> Prediction: ...


@dataclass(frozen=True)
class _Builtin:
    name: str

    def predict(self, scene: Scene) -> Prediction:
        from clutt3r_core.baselines import maskclustering_baseline, naive_baseline, segmentation_prediction

        cfg = method_config(self.name)
        if cfg is not None:
            from clutt3r_core.pipeline import segment

            return segmentation_prediction(segment(scene, cfg), self.name)
        if self.name == "naive":
            return naive_baseline(scene)
        if self.name == "maskclustering":
            return maskclustering_baseline(scene)
        raise SceneError(f"unknown method '{self.name}'")


def make_method(name: str) -> BenchMethod:
    """Factory of the built-in methods (registered in ``clutt3r_core.registry``)."""
    if name not in PRESET_OF and name not in ABLATION_METHODS and name not in ("naive", "maskclustering"):
        raise SceneError(f"unknown built-in method '{name}'")
    return _Builtin(name)


def _register_ablations() -> None:
    # Registered here, not in registry.py: the names come from config.ADDITIONS, which the
    # registry must not import (it stays free of numpy). Every process that can run a bench
    # job imports this module first (evaluation.jobs does), so workers know the names too.
    from clutt3r_core.registry import register_backend

    for name, desc in ABLATION_METHODS.items():
        register_backend("bench_method", name, "clutt3r_core.evaluation.methods:make_method",
                         description=desc, defaults={"name": name})


_register_ablations()
