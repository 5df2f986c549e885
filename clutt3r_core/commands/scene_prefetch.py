"""Start reading ``clutt3r segment``'s scene before the command line is parsed (issue 13).

Before a ``clutt3r segment`` process can read its scene it spends 0.1-0.25 s of one core on
pure Python: importing the configuration's modules (pointcloud, super-voxels, grouping, ...),
rich, the pipeline and the embedder registry, and, for command lines that are not plain
(``commands.segment_run.plain_arguments``), importing tyro and building the parser of
``SegmentConfig``'s ~70 fields. The scene's PNG decoders release the GIL, so the loading can
run beside that work, on the second core.

``start(args)`` is called by ``cli.main`` with the arguments after ``segment``, before any of
that is imported. It does not parse them: among the arguments that do not start with ``-``, it
looks for those that name a scene folder (what ``load_scene`` accepts), and if there is
exactly one, loads it on a daemon thread. The command line is then parsed as always, and
``take(scene)`` in the command returns the loaded scene only if the parsed ``SCENE`` is that
same path; otherwise (a guess that was wrong, ``--help``, a library call of the command)
it returns None and the command loads its scene itself. So the guess never decides anything:
it can cost wasted work, never a different result.

A loading error is kept and raised by ``take``, where the command would have raised it
(after the arguments were parsed: ``--help`` and bad arguments still answer first).
"""

from __future__ import annotations

import threading
from pathlib import Path

__all__ = ["scene_argument", "start", "take", "discard"]

_pending: tuple[Path, threading.Thread, list] | None = None


def _is_scene_folder(p: Path) -> bool:
    """What ``io.load_scene`` accepts (its detection, without reading anything)."""
    if p.is_file():
        return p.name in ("transforms.json", "scene_camera.json")
    return p.is_dir() and any(
        (p / rel).is_file() for rel in ("transforms.json", "scene_camera.json", "data/transforms.json")
    )


def scene_argument(args: list[str]) -> Path | None:
    """The one argument of ``args`` (those after ``segment``) that names a scene folder, or
    None when none or several do. A guess, checked by ``take`` against tyro's parse."""
    if "-h" in args or "--help" in args:  # tyro prints the help and exits: nothing to load
        return None
    found = [a for a in args if a and not a.startswith("-") and _is_scene_folder(Path(a))]
    return Path(found[0]) if len(found) == 1 else None


def _load(path: Path, box: list) -> None:
    from clutt3r_core.io import load_scene  # imported by start()

    try:
        box.append(load_scene(path, load_gt=False))
    except BaseException as e:  # noqa: BLE001  (kept for take(), which raises it in the command)
        box.append(e)


def start(args: list[str]) -> bool:
    """Begin loading the scene that ``args`` name (see the module docstring); whether it began.

    The thread is a daemon, but the loader's own pool threads are not: a process that ends
    early (a parse error) waits for the views already queued; ``--help`` starts nothing.
    """
    global _pending
    path = scene_argument(args)
    if path is None:
        return False
    # imported here, not on the thread: two threads importing at once can meet in a module
    # lock (importlib's _DeadlockError); cv2 and the readers are ~0.05 s of the 0.25
    import clutt3r_core.io  # noqa: F401
    box: list = []
    t = threading.Thread(target=_load, args=(path, box), name="clutt3r-scene-prefetch", daemon=True)
    t.start()
    _pending = (path, t, box)
    return True


def take(scene: Path) -> object | None:
    """The scene ``start`` loaded, if it loaded ``scene`` (``load_scene(scene, load_gt=False)``);
    None otherwise. Raises the loading's error. Hands the scene over once."""
    global _pending
    if _pending is None:
        return None
    path, t, box = _pending
    _pending = None
    if Path(scene) != path:
        return None
    t.join()
    if isinstance(box[0], BaseException):
        raise box[0]
    return box[0]


def discard() -> None:
    """Forget a scene ``start`` began that the command did not take (tyro refused the arguments):
    a later command in the same process loads its scene afresh, as it is then."""
    global _pending
    _pending = None
