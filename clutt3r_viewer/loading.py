"""Turning what the user gives (a run folder, a scene folder, objects) into ``ViewerData``.

A run folder is read with ``load_run`` (nothing is recomputed). Its scene (for images
and cameras) is found, in order: the ``scene`` argument (``--scene``, an override), the
scene folder the run recorded in ``run.json`` (``clutt3r_core.runs.run_scene_folder``),
the legacy link ``viewer.json`` in the run folder (``{"scene": "<path, relative to the
run folder or absolute>"}``, written by older versions), a ``scene/`` subfolder. Without
one, the viewer still shows the cloud, trees, graph and replay.

A recorded scene folder that no longer exists (moved or deleted) is an error naming
``run.json``, not a silent fallback: the user learns why the images are missing and
chooses ``--scene NEW_FOLDER`` or ``--no-images`` (``images=False``: view without them).

Hooks for data the core does not produce yet:
- ``register_update_loader(fn)``: ``fn(run_dir, scene) -> tuple[UpdateFrame, ...]`` adds
  post-interaction frames to replay (the Updates tab appears only when some exist). A loader
  that cannot read the run's updates (a ``Clutt3rError``: an unreadable ``update.json``, a
  correction log the chain was computed from that is gone or rewritten) does not keep the run
  from opening: it is shown without them, with an ``updates-unreadable`` run warning naming
  the file and the problem (the run, its edits and its update folders are left as they are).
- grasps: ``grasps.npz`` in the run folder (``GraspSet.load``); the Grasps tab appears only then.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from clutt3r_core.errors import Clutt3rError, SceneFileError
from clutt3r_core.runs import is_run_folder, read_run_info, run_scene_folder
from clutt3r_core.scene import Scene
from clutt3r_viewer.data import GraspSet, UpdateFrame, ViewerData, build_viewer_data

__all__ = [
    "is_run_dir",
    "is_scene_dir",
    "find_scene",
    "load_viewer_data",
    "register_update_loader",
    "load_updates",
    "text_embedder_for",
    "write_viewer_link",
]

UpdateLoader = Callable[[Path | None, Scene | None], tuple[UpdateFrame, ...]]
_UPDATE_LOADERS: list[UpdateLoader] = []


def register_update_loader(fn: UpdateLoader) -> UpdateLoader:
    """Register a source of post-interaction frames (see module docstring)."""
    _UPDATE_LOADERS.append(fn)
    return fn


def load_updates(run_dir: Path | None, scene: Scene | None,
                 problems: list[str] | None = None) -> tuple[UpdateFrame, ...]:
    """Every registered loader's frames. With ``problems`` (a list), a loader's ``Clutt3rError``
    is appended to it (one line) and its frames left out; without, it is raised."""
    out: list[UpdateFrame] = []
    for fn in _UPDATE_LOADERS:
        try:
            out.extend(fn(run_dir, scene))
        except Clutt3rError as e:
            if problems is None:
                raise
            problems.append(" ".join(str(e).split()))
    return tuple(out)


def is_run_dir(p: Path) -> bool:
    """A run folder (the core's one rule, ``clutt3r_core.runs.is_run_folder``)."""
    return is_run_folder(p)


def is_scene_dir(p: Path) -> bool:
    return (p / "transforms.json").is_file() or (p / "scene_camera.json").is_file() or (p / "data" / "transforms.json").is_file()


MOVED_HINT = "pass --scene NEW_FOLDER, or --no-images to view the run without its images"


def find_scene(run_dir: Path) -> Path | None:
    """The scene folder of a run folder, or None (module docstring).

    Raises ``SceneFileError`` naming run.json (recorded folder moved) or viewer.json (bad link).
    """
    run_dir = Path(run_dir)
    try:
        recorded = run_scene_folder(run_dir)
    except SceneFileError as e:
        info = read_run_info(run_dir)  # an unreadable run.json raises its own error here
        if info.scene is None:
            raise
        where = info.scene if info.scene.is_absolute() else f"{info.scene} (relative to the run folder)"
        raise SceneFileError(e.path, f"the run's scene folder {where} does not exist (moved or deleted?); "
                                     f"{MOVED_HINT}") from None
    if recorded is not None:
        if not is_scene_dir(recorded):
            raise SceneFileError(run_dir / "run.json",
                                 f"recorded scene folder {recorded} has no transforms.json / scene_camera.json; {MOVED_HINT}")
        return recorded
    link = run_dir / "viewer.json"
    if link.is_file():
        try:
            p = Path(json.loads(link.read_text())["scene"])
        except (json.JSONDecodeError, KeyError, TypeError) as e:
            raise SceneFileError(link, f"expected {{\"scene\": \"<folder>\"}}: {e}") from None
        p = p if p.is_absolute() else run_dir / p
        if not is_scene_dir(p):
            raise SceneFileError(link, f"linked scene folder {p} has no transforms.json / scene_camera.json")
        return p
    if is_scene_dir(run_dir / "scene"):
        return run_dir / "scene"
    return None


def write_viewer_link(run_dir: Path, scene_dir: Path) -> None:
    """Legacy: link a run to its scene in ``viewer.json``. New runs record their scene in run.json
    (``save_run(seg, out, scene_root=...)``); this stays for runs written without one."""
    from clutt3r_core.io.images import atomic_write_bytes

    try:
        rel = Path(scene_dir).resolve().relative_to(Path(run_dir).resolve())
        target = str(rel)
    except ValueError:
        target = str(Path(scene_dir).resolve())
    atomic_write_bytes(Path(run_dir) / "viewer.json", json.dumps({"scene": target}).encode())


def load_viewer_data(run_dir: Path, scene: Scene | Path | None = None, images: bool = True) -> ViewerData:
    """Read a saved run (and its scene, if found) without recomputing.

    ``scene`` overrides the recorded one; ``images=False`` skips the scene (no images, no
    error for a moved one).
    """
    from clutt3r_core.io import load_scene
    from clutt3r_core.runs import load_run

    run_dir = Path(run_dir)
    seg = load_run(run_dir)
    if scene is None and images:
        scene = find_scene(run_dir)
    if isinstance(scene, (str, Path)):
        scene = load_scene(scene)
    if scene is not None:  # candidates generated by the run (clutt3r segment --masks) live in RUN/instance_masks
        from clutt3r_core.masks import with_run_masks

        scene = with_run_masks(scene, run_dir)
    grasps = GraspSet.load(run_dir / "grasps.npz") if (run_dir / "grasps.npz").is_file() else None
    problems: list[str] = []
    updates = load_updates(run_dir, scene, problems)
    if problems:  # the run opens; what could not be read is said above the tabs (module docstring)
        from dataclasses import replace

        from clutt3r_core.diagnostics import RunWarning

        seg = replace(seg, warnings=tuple(seg.warnings) + tuple(
            RunWarning("updates-unreadable", f"{p}; the run is shown without its updates") for p in problems))
    return build_viewer_data(seg, scene, grasps=grasps, updates=updates)


def text_embedder_for(data: ViewerData, override=None):
    """The embedder that can place text in the space of the run's mask embeddings, or None.

    ``override`` (an embedder object) wins. Otherwise the run's own embedder (by the name
    in its trace) is created and asked for one text embedding; a backend without text
    support (no ``embed_text``, e.g. 'appearance-hsv') or one that is not installed
    gives None, and the Query tab is not shown.
    """
    from clutt3r_core.embeddings import create_embedder

    emb = override
    if emb is None:
        try:
            emb = create_embedder(data.trace.embedder)
        except (Clutt3rError, ImportError, TypeError):
            return None
    from clutt3r_core.embeddings import has_text

    if not has_text(emb):
        return None
    try:
        t = emb.embed_text(["object"])
    except NotImplementedError:
        return None
    if t.ndim != 2 or t.shape[1] != data.trace.embeddings.shape[1]:
        return None
    return emb
