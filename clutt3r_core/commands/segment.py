"""``clutt3r segment SCENE --out RUN``: segment a scene folder and write the run folder."""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
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
    from rich.console import Console
    from rich.markup import escape

    from clutt3r_core.commands import scene_prefetch
    from clutt3r_core.commands.masks import mask_choice
    from clutt3r_core.io import load_scene
    from clutt3r_core.io.images import write_png

    if preset:
        config = PRESETS[preset]
    console = Console(stderr=True)
    # ours (issue 13, whole-command time): a second thread imports the rest of the command and
    # builds the embedder (the registry reads the installed entry points) while this one loads
    # the scene (its decoders release the GIL). The loading stays on this thread, so its
    # errors come first, as before.
    with ThreadPoolExecutor(1) as pool:
        preparing = pool.submit(_prepare, config.embedder)
        with console.status(f"loading {scene}"):
            # the CLI may have begun loading it before parsing (commands.scene_prefetch); the
            # ground truth is never read here (it does not enter the segmentation)
            sc = scene_prefetch.take(scene)
            if sc is None:
                sc = load_scene(scene, load_gt=False)
        segment, save_run, overview_sheet, embedder = preparing.result()  # re-raises its error
    masks = mask_choice(mask_options)
    if masks != "auto" or not all(v.masks is not None for v in sc.initial_views):
        why = f"--masks {mask_options.masks}" if masks != "auto" else "the scene has no mask candidates"
        console.print(f"mask candidates: generator [bold]{getattr(masks, 'name', 'builtin')}[/] ({why})")
    seg = segment(sc, config, embedder=embedder, progress=True, masks=masks)
    if seg.masks.generated:
        n = sum(len(c) for c in seg.masks.candidates)
        console.print(f"mask candidates: {n} on {len(seg.masks.frames)} views in {seg.masks.seconds:.1f} s")
    # the folder load_scene read (a release sample's data/ inside SCENE), so the viewer finds the images
    # (save_run also writes generated candidates to OUT/instance_masks/ and their generator to run.json)
    # overview.png's tiles are drawn on two threads while save_run writes (numpy, OpenCV and
    # zlib release the GIL; neither reads what the other writes): issue 13, whole-command wall
    # time. Three workers: one assembles the sheet and waits while the other two draw.
    with ThreadPoolExecutor(3) as pool:
        sheet = pool.submit(overview_sheet, seg.points, seg.instance, sc, map=pool.map)
        save_run(seg, out, scene_root=sc.root if sc.root is not None else scene)
        write_png(Path(out) / "overview.png", sheet.result(), sub_filter=True)  # re-raises the drawing's error
    for w in seg.warnings:  # also in OUT/run.json; soft_wrap: one line each, however narrow the terminal
        console.print(f"[yellow]warning:[/] {escape(w.message)}", soft_wrap=True, highlight=False)
    t = seg.trace
    console.print(
        f"[bold]{sc.name}[/]: {seg.num_instances} instances from {int(t.nodes.is_leaf.sum())} leaves "
        f"({len(t.grouping.merges)} merges, {len(t.grouping.substitutions)} substitutions), "
        f"{len(seg.points)} points; core {sum(x.seconds for x in t.timings):.2f} s -> {out}"
    )


def _prepare(embedder_name: str):
    """The command's later imports and its embedder: (segment, save_run, overview_sheet, embedder)."""
    import numpy.random  # noqa: F401  (the support plane's RANSAC; 30 ms, imported lazily by numpy)
    from tqdm import tqdm  # noqa: F401  (the pipeline's progress bar)

    from clutt3r_core.embeddings import create_embedder
    from clutt3r_core.pipeline import segment
    from clutt3r_core.runs import save_run
    from clutt3r_core.visualize import overview_sheet

    return segment, save_run, overview_sheet, create_embedder(embedder_name)
