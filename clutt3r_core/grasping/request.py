"""Build a ``GraspRequest`` from a segmentation run (and its scene, for the unseen-space check)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError
from clutt3r_core.grasping import DepthView, GraspRequest

__all__ = ["request_from_segmentation", "depth_views", "run_views", "request_from_run"]


def depth_views(scene) -> tuple[DepthView, ...]:
    """The initial views of a ``Scene`` that have depth, as ``DepthView``s (the views that were fused)."""
    return tuple(DepthView(v.camera, v.depth) for v in scene.initial_views if v.depth is not None)


def request_from_segmentation(seg, instance: int, views: tuple[DepthView, ...] = (),
                              target: np.ndarray | None = None) -> GraspRequest:
    """The request for ``instance`` of a ``pipeline.Segmentation`` (its whole fused cloud, support included).

    ``target``: an explicit (N,) bool target mask instead of ``seg.instance == instance``
    (e.g. ground-truth labels in the benchmark).
    """
    k = int(instance)
    if target is None:
        if not 0 <= k < seg.num_instances:
            raise SceneError(f"instance {k} does not exist: the run has instances 0..{seg.num_instances - 1}")
        target = np.asarray(seg.instance) == k
    return GraspRequest(points=seg.points, normals=seg.normals, target=np.asarray(target, bool), instance=k,
                        views=tuple(views))


def run_views(run_dir: str | Path, scene: str | Path | None = None) -> tuple[tuple[DepthView, ...], str]:
    """(depth views of the run's scene, a warning or '') for the unseen-space check.

    The scene is ``scene`` when given, else the one the run recorded (``runs.run_scene_folder``).
    When neither is known, or the scene cannot be read, the views are empty and the warning says
    that only the fused cloud is checked for collisions.
    """
    from clutt3r_core.io import load_scene

    folder: Path | None = Path(scene) if scene is not None else None
    if folder is None:
        try:
            from clutt3r_core.runs import run_scene_folder

            folder = run_scene_folder(run_dir)
        except ImportError:
            folder = None
        except Clutt3rError as e:
            return (), f"{e}; collision checks use the fused cloud only (no unseen-space check)"
    if folder is None:
        return (), ("the run does not record its scene folder (pass --scene); collision checks use the fused "
                    "cloud only (no unseen-space check)")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sc = load_scene(folder)
    except Clutt3rError as e:
        return (), f"scene {folder} unreadable ({e}); collision checks use the fused cloud only"
    views = depth_views(sc)
    if not views:
        return (), f"scene {folder} has no depth; collision checks use the fused cloud only"
    return views, ""


def request_from_run(run_dir: str | Path, instance: int, scene: str | Path | None = None):
    """(request, segmentation, warning) for ``instance`` of the run in ``run_dir``."""
    from clutt3r_core.runs import load_run

    seg = load_run(run_dir)
    views, warn = run_views(run_dir, scene)
    return request_from_segmentation(seg, instance, views), seg, warn
