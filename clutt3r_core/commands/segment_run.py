"""The body of ``clutt3r segment`` (``run_segment``), importable without tyro, and the plain
command lines the CLI runs without building tyro's parser (``plain_arguments``).

Why (issue 13, the whole command under 2 s at 640x480): importing tyro and building the parser
of ``SegmentConfig``'s ~70 nested fields cost ~0.14 s of one core's CPU in every process (0.09 s
import, 0.05 s parser), for a command line that is almost always ``SCENE --out RUN`` with at most
a ``--preset``. Those forms are recognised here; every other command line (``--help``, any
``--config.*`` or ``--masks`` option, a repeated or misspelt option, ``--``, a value starting with
``-``) goes to tyro, the parser of record, as before. A test runs tyro on the same argument lists
(hypothesis) and checks it parses them to the same call.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from clutt3r_core.commands.masks import MaskOptions
    from clutt3r_core.config import SegmentConfig

__all__ = ["plain_arguments", "run_segment"]


def plain_arguments(args: list[str]) -> tuple[Path, Path, str] | None:
    """(scene, out, preset or "") when ``args`` (those after ``segment``) are one positional
    SCENE, ``--out RUN`` and at most one ``--preset NAME`` (either as ``--opt=value``), in any
    order; None for anything else (tyro parses it)."""
    from clutt3r_core.config import PRESETS

    positional: list[str] = []
    opts: dict[str, str] = {}
    i = 0
    while i < len(args):
        a = args[i]
        if not a or a == "-":
            return None
        if not a.startswith("-"):
            positional.append(a)
            i += 1
            continue
        name, eq, value = a.partition("=")
        if name not in ("--out", "--preset") or name in opts:
            return None
        if not eq:
            if i + 1 >= len(args):
                return None
            value = args[i + 1]
            i += 1
        if not value or value.startswith("-"):
            return None
        opts[name] = value
        i += 1
    if len(positional) != 1 or "--out" not in opts:
        return None
    preset = opts.get("--preset", "")
    if preset and preset not in PRESETS:
        return None
    return Path(positional[0]), Path(opts["--out"]), preset


def run_segment(scene: Path, out: Path, config: SegmentConfig, mask_options: MaskOptions | None = None) -> None:
    """Segment a scene folder and write the run to OUT (``segment_command``'s body; its docstring
    describes the arguments). ``mask_options`` None: the defaults (``--masks auto``)."""
    from rich.console import Console
    from rich.markup import escape

    from clutt3r_core.io import load_scene
    from clutt3r_core.io.images import write_png

    console = Console(stderr=True)
    # ours (issue 13, whole-command time): a second thread imports the rest of the command and
    # builds the embedder (the registry reads the installed entry points) while this one loads
    # the scene (its decoders release the GIL). The loading stays on this thread, so its
    # errors come first, as before.
    with ThreadPoolExecutor(1) as pool:
        preparing = pool.submit(_prepare, config.embedder)
        with console.status(f"loading {scene}"):
            # the ground truth is never read here (it does not enter the segmentation)
            sc = load_scene(scene, load_gt=False)
        segment, save_run, overview_sheet, embedder = preparing.result()  # re-raises its error
    if mask_options is None:
        masks, choice = "auto", "auto"
    else:
        from clutt3r_core.commands.masks import mask_choice

        masks, choice = mask_choice(mask_options), mask_options.masks
    if masks != "auto" or not all(v.masks is not None for v in sc.initial_views):
        why = f"--masks {choice}" if masks != "auto" else "the scene has no mask candidates"
        console.print(f"mask candidates: generator [bold]{getattr(masks, 'name', 'builtin')}[/] ({why})")
    seg = segment(sc, config, embedder=embedder, progress=True, masks=masks)
    if seg.masks.generated:
        n = sum(len(c) for c in seg.masks.candidates)
        console.print(f"mask candidates: {n} on {len(seg.masks.frames)} views in {seg.masks.seconds:.1f} s")
    # the folder load_scene read (a release sample's data/ inside SCENE), so the viewer finds the images
    # (save_run also writes generated candidates to OUT/instance_masks/ and their generator to run.json)
    # overview.png's tiles are drawn on two threads while save_run writes, and the sheet is
    # encoded there too (numpy, OpenCV and zlib release the GIL; neither reads what the other
    # writes): issue 13, whole-command wall time. Three workers: one assembles and encodes the
    # sheet, waiting while the other two draw its tiles.
    def draw_overview() -> None:
        sheet = overview_sheet(seg.points, seg.instance, sc, map=pool.map)
        write_png(Path(out) / "overview.png", sheet, sub_filter=True)

    with ThreadPoolExecutor(3) as pool:
        drawing = pool.submit(draw_overview)
        save_run(seg, out, scene_root=sc.root if sc.root is not None else scene)
        drawing.result()  # re-raises the drawing's error
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
