"""Synthetic cluttered-tabletop scenes (YCB meshes, pybullet piles, CPU ray casting, noisy masks).

Public entry points: ``SynthConfig``, ``generate_scene``, ``generate``, ``write_synth_scene``,
``load_synth_info`` (see ``generator.py`` and README.md in this folder).
"""

from clutt3r_core.synth.generator import (
    DIFFICULTY_PRESETS,
    SynthConfig,
    SynthInfo,
    SynthResult,
    generate,
    generate_scene,
    load_synth_info,
    synth_info,
    write_synth_scene,
)

__all__ = ["DIFFICULTY_PRESETS", "SynthConfig", "SynthInfo", "SynthResult", "generate", "generate_scene",
           "load_synth_info", "synth_info", "write_synth_scene"]
