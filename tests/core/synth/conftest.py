"""Tiny synthetic scenes shared by the synth tests (3 objects, 2 views, 160x120: about a second each)."""

from __future__ import annotations

import pytest

from clutt3r_core.synth.generator import SynthConfig, SynthResult, generate

TINY = dict(n_objects=3, views=2, width=160, height=120)


def tiny_config(seed: int = 0, **kw) -> SynthConfig:
    return SynthConfig(seed=seed, **{**TINY, **kw})


_CACHE: dict[SynthConfig, SynthResult] = {}


def tiny(seed: int = 0, **kw) -> SynthResult:
    cfg = tiny_config(seed, **kw)
    if cfg not in _CACHE:
        _CACHE[cfg] = generate(cfg, progress=False)
    return _CACHE[cfg]


@pytest.fixture(scope="session")
def tiny_scene() -> SynthResult:
    return tiny(0, depth_noise="none")


@pytest.fixture(scope="session")
def tiny_prepost() -> SynthResult:
    return tiny(1, prepost=True)
