"""One tiny generated scene segmented once per test session (shared by the run / config / rule tests)."""

from __future__ import annotations

import functools

from clutt3r_core.pipeline import Segmentation, segment
from clutt3r_core.scene import Scene
from clutt3r_core.synth import SynthConfig, generate_scene


@functools.lru_cache(maxsize=1)
def tiny_scene() -> Scene:
    return generate_scene(
        SynthConfig(seed=0, preset="easy", views=3, width=320, height=240, n_objects=3), progress=False
    )


@functools.lru_cache(maxsize=1)
def tiny_segmentation() -> Segmentation:
    return segment(tiny_scene())
