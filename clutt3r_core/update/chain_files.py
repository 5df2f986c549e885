"""A run's update chain as files: its steps, each update's ``update.json``, the post views' cameras.

``RUN/updates/NN_frame_FFFFFF/`` (``update.state``) holds one update each; these helpers read what
the scene after an update (``update.scene_after``), ``clutt3r query`` and ``clutt3r grasp`` need of
them besides the state: how many steps there are (``chain_length``, ``resolve_step``), the
updates' records (``update_docs``), which instances came from which post-view mask
(``added_masks``) and where each post view's camera stood (``post_camera``, ``post_cameras``,
``post_eyes``: the added instances' normals face it). The names are importable from
``update.scene_after`` too (where the commands and the viewer import them).
"""

from __future__ import annotations

import json
from pathlib import Path

from clutt3r_core.errors import Clutt3rError, SceneError, SceneFileError

__all__ = ["chain_length", "resolve_step", "update_docs", "added_masks", "post_camera", "post_cameras", "post_eyes"]


def chain_length(run_dir: str | Path) -> int:
    from clutt3r_core.update.state import state_dirs

    return len(state_dirs(run_dir))


def resolve_step(run_dir: str | Path, step: int | None) -> int:
    """``step`` checked against the run's chain (None = its latest state); one clear error."""
    n = chain_length(run_dir)
    if step is None:
        return n
    if not 0 <= int(step) <= n:
        raise Clutt3rError(f"{run_dir}: --step {step} does not exist: the run has {n} update(s) "
                           f"(steps 0..{n}; 0 = the run as segmented)")
    return int(step)


def update_docs(run_dir: str | Path, step: int) -> list[tuple[Path, dict]]:
    """(path, parsed ``update.json``) of the first ``step`` updates of the run's chain."""
    from clutt3r_core.update.state import state_dirs

    out = []
    for d in state_dirs(run_dir)[:step]:
        try:
            out.append((d / "update.json", json.loads((d / "update.json").read_text())))
        except (OSError, json.JSONDecodeError) as e:
            raise SceneFileError(d / "update.json", f"unreadable update ({e})") from None
    return out


def added_masks(run_dir: str | Path, step: int,
                docs: list[tuple[Path, dict]] | None = None) -> list[tuple[int, int, int]]:
    """(instance id, frame, mask id in that post view) of every instance the first ``step``
    updates added from a mask candidate (``update.json`` "new_masks"; ``docs``: ``update_docs``
    when already read)."""
    docs = update_docs(run_dir, step) if docs is None else docs
    return [(int(m["instance"]), int(doc["frame"]), int(m["mask"])) for _, doc in docs
            for m in doc.get("new_masks", []) if m.get("instance") is not None]


def post_camera(path: Path, doc: dict):
    """The post view's ``Camera`` an update's ``update.json`` (``path``, parsed ``doc``) records
    as "camera" (written since session 8), else None (older updates); ``SceneFileError`` when invalid."""
    from clutt3r_core.scene import Camera

    if doc.get("camera") is None:
        return None
    try:
        return Camera.from_json(doc["camera"])
    except (KeyError, TypeError, ValueError, SceneError) as e:
        raise SceneFileError(path, f"invalid \"camera\" ({e})") from None


def post_cameras(run_dir: str | Path, step: int, docs: list[tuple[Path, dict]] | None = None) -> dict:
    """{frame: ``Camera``} of the post views of the first ``step`` updates that record one
    (``post_camera``; ``docs``: ``update_docs`` when already read)."""
    cams = ((int(doc["frame"]), post_camera(path, doc)) for path, doc in
            (update_docs(run_dir, step) if docs is None else docs))
    return {f: c for f, c in cams if c is not None}


def post_eyes(run_dir: str | Path, step: int, scene: str | Path | None = None) -> dict:
    """{frame: camera centre (3,) world metres} of the post views of the first ``step`` updates that
    added an instance, to orient the added instances' normals (``oriented_normals``): the camera its
    ``update.json`` records (since session 8), else the scene folder's view of that frame (``scene``,
    else the one the run records; updates written before, ~0.2 s to load it); a frame with neither is
    left out (+z). ``clutt3r query`` and ``clutt3r grasp`` both read it, so an added instance has
    one set of normals whichever asks."""
    docs = update_docs(run_dir, step)
    frames = {f for _, f, _ in added_masks(run_dir, step, docs)}
    eyes = {f: c.T_world_camera[:3, 3] for f, c in post_cameras(run_dir, step, docs).items() if f in frames}
    if frames - set(eyes):
        try:
            from clutt3r_core.io import load_scene
            from clutt3r_core.runs import run_scene_folder

            folder = Path(scene) if scene is not None else run_scene_folder(run_dir)
            if folder is not None:
                for v in load_scene(folder, load_gt=False).views:
                    if v.frame in frames and v.frame not in eyes:
                        eyes[v.frame] = v.camera.T_world_camera[:3, 3]
        except Clutt3rError:
            pass  # no scene folder: +z (oriented_normals says so)
    return eyes
