"""Benchmark methods behind one protocol (registry kind ``bench_method``).

Every method maps a scene (fused the same way) to a ``Prediction``; the built-in ones are
Clutt3R's presets and the two baselines.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

from clutt3r_core.baselines.common import Prediction
from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Scene

__all__ = ["BenchMethod", "make_method", "PRESET_OF"]

PRESET_OF = {"ours": "default", "paper": "paper", "no-spatial": "no-spatial", "no-substitution": "no-substitution"}
"""Benchmark method name -> segmentation preset."""


@runtime_checkable
class BenchMethod(Protocol):
    name: str

    def predict(self, scene: Scene) -> Prediction: ...


@dataclass(frozen=True)
class _Builtin:
    name: str

    def predict(self, scene: Scene) -> Prediction:
        from clutt3r_core.baselines import maskclustering_baseline, naive_baseline, segmentation_prediction

        if self.name in PRESET_OF:
            from clutt3r_core.pipeline import PRESETS, segment

            return segmentation_prediction(segment(scene, PRESETS[PRESET_OF[self.name]]), self.name)
        if self.name == "naive":
            return naive_baseline(scene)
        if self.name == "maskclustering":
            return maskclustering_baseline(scene)
        raise SceneError(f"unknown method '{self.name}'")


def make_method(name: str) -> BenchMethod:
    """Factory of the built-in methods (registered in ``clutt3r_core.registry``)."""
    if name not in PRESET_OF and name not in ("naive", "maskclustering"):
        raise SceneError(f"unknown built-in method '{name}'")
    return _Builtin(name)
