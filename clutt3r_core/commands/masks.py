"""``clutt3r masks SCENE --out DIR``: mask candidates alone; and the ``--masks`` options of
``clutt3r segment`` (``MaskOptions``, ``prepare_masks``, ``record_run_masks``).

Candidates are written as ``mask_{frame:06d}_{id:02d}.png`` (the sample layout's
``instance_masks/``), so they can be inspected, corrected, and reused with
``--masks import --mask-source DIR``.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
from tyro.conf import Positional

__all__ = ["MaskOptions", "MaskChoice", "masks_command", "prepare_masks", "record_run_masks", "make_generator"]

MaskChoice = Literal["auto", "builtin", "import", "sam-onnx"]


@dataclass(frozen=True)
class MaskOptions:
    """Where a view's mask candidates come from."""

    masks: MaskChoice = "auto"
    """auto: the scene's own instance_masks/ when it has them, else the builtin generator;
    builtin: multi-scale RGB-D segmentation (no weights); import: read --mask-source;
    sam-onnx: a SAM-family ONNX encoder/decoder pair (--sam-encoder, --sam-decoder)."""
    mask_source: Path | None = None
    """import: a mask PNG folder, a folder of per-view .npz / .json, or one COCO JSON file."""
    sam_encoder: Path | None = None
    """sam-onnx: local path of the image encoder .onnx."""
    sam_decoder: Path | None = None
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


def prepare_masks(scene, opts: MaskOptions, console=None):
    """(scene with candidates on every initial view, generator name or None if the scene's own).

    ``auto`` keeps a scene's own candidates and fills views without any with the builtin
    generator; any other choice replaces every initial view's candidates.
    """
    from clutt3r_core.masks import fill_masks, scene_has_masks

    if opts.masks == "auto" and scene_has_masks(scene):
        return scene, None
    gen = make_generator(opts)
    if console is not None:
        why = "the scene has no mask candidates" if opts.masks == "auto" else f"--masks {opts.masks}"
        console.print(f"mask candidates: generator [bold]{gen.name}[/] ({why}), {len(scene.initial)} views")
    t = time.perf_counter()
    out = fill_masks(scene, gen, only_missing=opts.masks == "auto", progress=console is not None)
    if console is not None:
        n = sum(len(v.masks) for v in out.initial_views)
        console.print(f"mask candidates: {n} in {time.perf_counter() - t:.1f} s")
    return out, gen.name


def record_run_masks(run_dir: str | Path, scene, generator: str | None) -> None:
    """Write generated candidates to RUN/instance_masks/ and name their generator in run.json
    (key ``masks``: {"generator", "folder"}); ``generator=None`` records "scene"."""
    from clutt3r_core.io.images import atomic_write_bytes
    from clutt3r_core.masks import write_masks

    run_dir = Path(run_dir)
    rec = {"generator": generator or "scene", "folder": None}
    if generator is not None:
        write_masks(scene, run_dir / "instance_masks")
        rec["folder"] = "instance_masks"
    path = run_dir / "run.json"
    d = json.loads(path.read_text()) if path.is_file() else {}
    d["masks"] = rec
    atomic_write_bytes(path, json.dumps(d).encode())


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
