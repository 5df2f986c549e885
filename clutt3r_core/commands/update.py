"""``clutt3r update RUN --frame F``: update a run's scene from one post-interaction image (Sec. III-C)."""

from __future__ import annotations

import json
from pathlib import Path

from tyro.conf import Positional

from clutt3r_core.update.types import STATUSES, UpdateConfig

__all__ = ["update_command"]


def update_command(
    run: Positional[Path],
    frame: int | None = None,
    image: Path | None = None,
    depth: Path | None = None,
    masks: Path | None = None,
    camera: Path | None = None,
    scene: Path | None = None,
    out: Path | None = None,
    config: UpdateConfig = UpdateConfig(),
    embedder: str = "run",
    overlay: bool = True,
    recompute: bool = False,
) -> None:
    """Update the scene state from one post-interaction image and write update.json.

    The update starts from the last state of RUN's chain (RUN/updates/*), so running frame 8
    then frame 9 chains the two updates; RUN may also be a state folder to start from.
    Step 0 is the run's labelling after its corrections (the viewer's Edit tab; the ids are
    the corrected ids). A chain computed before later corrections is stale: refused, with the
    way out (``--recompute``).

    Args:
        run: run folder (from ``clutt3r segment``) or an update state folder.
        frame: a post-interaction frame of the run's scene (clutt3r_scene.json post_frames,
            instance_tree.json updates, or frames without depth).
        image: instead of --frame: an RGB image from outside the scene (needs --masks and --camera).
        depth: with --image: optional 16-bit depth PNG in millimetres.
        masks: with --image: folder of the image's mask candidate PNGs (mask_*_NN.png, NN = id).
        camera: with --image: camera JSON (K/width/height/T_world_camera, or a nerfstudio frame).
        scene: the scene folder (default: the one the run recorded).
        out: state folder to write (default RUN/updates/NN_frame_FFFFFF).
        config: association, change detection and pose settings (paper values, Sec. IV).
        embedder: mask embedder for S_semantic: "run" (default) = the run's own embedder;
            "auto" = the learned imagenet-minilm when the language extra is installed (measured
            no better on the evaluation pairs, docs/update.md); or a registry name. The
            stored instances are re-embedded from the run's views when needed (cached in
            RUN/query_cache.npz); the name is recorded in update.json and state.json.
        overlay: also write overlay.png (before | after on the new image).
        recompute: start a new chain from the run's current (corrected) labelling: the existing
            RUN/updates is moved aside to RUN/updates.stale-YYYYmmdd-HHMMSS (nothing deleted).
    """
    from rich.console import Console

    from clutt3r_core.errors import Clutt3rError, SceneFileError
    from clutt3r_core.io.images import write_png
    from clutt3r_core.update.state import apply_update, latest_state, load_state, save_state

    console = Console(stderr=True)
    if (frame is None) == (image is None):
        raise SystemExit("clutt3r update: give exactly one of --frame F or --image PATH (with --masks and --camera)")
    from clutt3r_core.update.run_labels import stale_note

    if recompute:
        if (run / "state.json").is_file():
            raise SystemExit("clutt3r update: --recompute takes the run folder, not a state folder")
        if (run / "updates").is_dir():
            import time

            aside = run / f"updates.stale-{time.strftime('%Y%m%d-%H%M%S')}"
            (run / "updates").rename(aside)
            console.print(f"moved the previous update chain to {aside} (kept); starting from the run's labelling")
    if (run / "state.json").is_file():
        state, parent = load_state(run), run
        run_dir = state.run if state.run is not None else run.parent.parent
    else:
        run_dir = run
        state, parent = latest_state(run)
    note = stale_note(run_dir, frame=frame)
    if note is not None:
        # extending it would mix two labellings' ids in one chain
        raise Clutt3rError(note)
    if image is not None:
        if masks is None or camera is None:
            raise SystemExit("clutt3r update: --image needs --masks DIR and --camera FILE")
        from clutt3r_core.update.inputs import read_external_view

        view = read_external_view(image, masks, camera, depth)
    else:
        from clutt3r_core.io import load_scene
        from clutt3r_core.runs import run_scene_folder

        scene_dir = scene if scene is not None else run_scene_folder(run_dir)
        if scene_dir is None:
            raise SceneFileError(Path(run_dir) / "run.json", "the run records no scene folder; pass --scene")
        with console.status(f"loading {scene_dir}"):
            sc = load_scene(scene_dir)
        post = [v.frame for v in sc.post_views]
        if frame not in post:
            raise SceneFileError(scene_dir, f"frame {frame} is not a post-interaction frame of the scene "
                                            f"(post frames: {post or 'none'})")
        view = sc.view_by_frame(frame)
        if view.masks is None:
            raise SceneFileError(scene_dir, f"post-interaction frame {frame} has no mask candidates")
    from clutt3r_core.update.embed import resolve_embedder, with_embedder

    name = resolve_embedder(embedder, state)
    if name != state.embedder:
        with console.status(f"embedding the stored instances with {name}"):
            state = with_embedder(state, name, scene=scene if image is not None else scene_dir)
    done = [h.frame for h in state.history]
    if image is None and frame in done:
        raise Clutt3rError(f"frame {frame} was already applied in this chain (steps {done}); "
                           "pass an earlier state folder as RUN to redo it")
    from clutt3r_core.update.update import update_scene

    with console.status(f"updating from frame {view.frame}"):
        result = update_scene(state, view, config)
    new_state = apply_update(state, result)
    out = out if out is not None else Path(run_dir) / "updates" / f"{new_state.step:02d}_frame_{view.frame:06d}"
    save_state(new_state, out, result, parent=parent)
    if overlay:
        from clutt3r_core.update.overlay import update_overlay

        write_png(out / "overlay.png", update_overlay(state, view, result))
    counts = {s: len(result.by_status(s)) for s in STATUSES}
    console.print(f"frame {view.frame}: " + ", ".join(f"{n} {s}" for s, n in counts.items())
                  + f", {len(result.new_masks)} new masks; {result.time_s:.2f} s -> {out / 'update.json'}")
    print(json.dumps(result.to_json()))
