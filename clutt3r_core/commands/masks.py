"""``clutt3r masks SCENE --out DIR``: mask candidates alone; and the ``--masks`` options of
``clutt3r segment`` (``MaskOptions``, ``mask_choice``; the rule itself is
``clutt3r_core.masks.ensure_candidates``, which ``pipeline.segment`` applies).

Candidates are written as ``mask_{frame:06d}_{id:02d}.png`` (the sample layout's
``instance_masks/``), so they can be inspected, corrected, and reused with
``--masks import --mask-source DIR``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal, Optional

import tyro
from tyro.conf import Positional

__all__ = ["MaskOptions", "MaskChoice", "masks_command", "mask_choice", "make_generator"]

MaskChoice = Literal["auto", "builtin", "import", "sam-onnx"]


@dataclass(frozen=True)
class MaskOptions:
    """Where a view's mask candidates come from."""

    masks: MaskChoice = "auto"
    """auto: the scene's own instance_masks/ when it has them, else the builtin generator;
    builtin: multi-scale RGB-D segmentation (no weights); import: read --mask-source;
    sam-onnx: a SAM-family ONNX encoder/decoder pair (--sam-encoder, --sam-decoder)."""
    # Optional[Path], not Path | None: tyro checks the defaults of X | None types with
    # typeguard, whose import (unittest.mock, asyncio) cost every `clutt3r segment` 50-100 ms
    mask_source: Optional[Path] = None  # noqa: UP007
    """import: a mask PNG folder, a folder of per-view .npz / .json, or one COCO JSON file."""
    sam_encoder: Optional[Path] = None  # noqa: UP007
    """sam-onnx: local path of the image encoder .onnx."""
    sam_decoder: Optional[Path] = None  # noqa: UP007
    """sam-onnx: local path of the prompt decoder .onnx."""


def make_generator(opts: MaskOptions):
    """The generator named by ``opts`` (``auto`` -> builtin)."""
    from clutt3r_core.masks import create_mask_generator

    name = "builtin" if opts.masks == "auto" else opts.masks
    if name == "import":
        return create_mask_generator("import", source=opts.mask_source)
    if name == "sam-onnx":
        return create_mask_generator("sam-onnx", encoder=opts.sam_encoder, decoder=opts.sam_decoder)
    return create_mask_generator(name)


def mask_choice(opts: MaskOptions):
    """``pipeline.segment``'s ``masks`` argument for ``opts``: ``"auto"`` (the scene's own, the
    builtin generator where it has none) or the generator object (which replaces them)."""
    return "auto" if opts.masks == "auto" else make_generator(opts)


def masks_command(
    scene: Positional[Path],
    out: Path,
    options: Annotated[MaskOptions, tyro.conf.arg(name="")] = MaskOptions(masks="builtin"),
    all_views: bool = False,
) -> None:
    """Generate mask candidates for a scene's views and write them to OUT.

    Files: OUT/mask_{frame:06d}_{id:02d}.png (the sample layout's instance_masks/ naming;
    ids 1..M, three digits from 100 on).

    Args:
        scene: scene folder (transforms.json or scene_camera.json inside).
        out: folder to write the mask PNGs to.
        options: which generator (default here: builtin, even when the scene has candidates).
        all_views: also the post-interaction views (default: the initial views).
    """
    import dataclasses

    from rich.console import Console

    from clutt3r_core.io import load_scene
    from clutt3r_core.masks import fill_masks, write_masks

    console = Console(stderr=True)
    with console.status(f"loading {scene}"):
        sc = load_scene(scene)
    if options.masks == "auto" and all(v.masks is not None for v in sc.initial_views):
        console.print("--masks auto: the scene has candidates already; writing them as they are")
        gen_name = "scene"
    else:
        gen = make_generator(options)
        gen_name = gen.name
        if all_views:  # every view counts as initial for generation; roles are kept in the scene
            sc2 = dataclasses.replace(sc, initial=tuple(range(len(sc.views))), post=())
            t = time.perf_counter()
            sc2 = fill_masks(sc2, gen, progress=True)
            sc = dataclasses.replace(sc2, initial=sc.initial, post=sc.post)
        else:
            t = time.perf_counter()
            sc = fill_masks(sc, gen, progress=True)
        console.print(f"generator {gen_name}: {time.perf_counter() - t:.1f} s")
    paths = write_masks(sc, out, views="all" if all_views else "initial")
    counts = ", ".join(f"{v.frame}: {len(v.masks)}" for v in (sc.views if all_views else sc.initial_views)
                       if v.masks is not None)
    console.print(f"[bold]{sc.name}[/]: {len(paths)} masks ({gen_name}) -> {out}  (per frame {counts})")
