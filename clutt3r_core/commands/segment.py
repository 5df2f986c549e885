"""``clutt3r segment SCENE --out RUN``: segment a scene folder and write the run folder.

The body is ``commands.segment_run.run_segment``, which imports no tyro: the CLI runs the plain
command lines (``SCENE --out RUN [--preset P]``) through it without building this parser
(issue 13; ``segment_run.plain_arguments``)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import tyro

from tyro.conf import Positional

from clutt3r_core.commands.masks import MaskOptions

from clutt3r_core.config import PRESETS, PresetName, SegmentConfig

__all__ = ["segment_command"]


def segment_command(
    scene: Positional[Path],
    out: Path,
    config: SegmentConfig = SegmentConfig(),
    preset: Literal["", PresetName] = "",  # nested Literal flattens: "" or a preset name
    mask_options: Annotated[MaskOptions, tyro.conf.arg(name="")] = MaskOptions(),
) -> None:
    """Segment a scene folder (sample layout or BOP) and write the run to OUT.

    Args:
        scene: scene folder (transforms.json or scene_camera.json inside).
        out: run folder to write (instances.npz, instances.ply, instance_tree.json, trace/).
        config: every stage's settings (paper defaults, Sec. IV).
        preset: if set, one of default / paper / no-spatial / no-substitution / noisy-depth (ours with
            the multi-view surface estimate, for consumer depth cameras); replaces --config.
        mask_options: where the mask candidates come from (--masks auto|builtin|import|sam-onnx);
            generated ones are written to OUT/instance_masks/ and named in OUT/run.json.
    """
    from clutt3r_core.commands.segment_run import run_segment

    run_segment(scene, out, PRESETS[preset] if preset else config, mask_options)
