"""Build a ``GraspRequest`` from a segmentation run (and its scene, for the unseen-space check)."""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError
from clutt3r_core.grasping import DepthView, GraspRequest

__all__ = ["request_from_segmentation", "depth_views", "run_views", "request_from_run", "scene_now"]


def depth_views(scene) -> tuple[DepthView, ...]:
    """The initial views of a ``Scene`` that have depth, as ``DepthView``s (the views that were fused)."""
    return tuple(DepthView(v.camera, v.depth) for v in scene.initial_views if v.depth is not None)


def request_from_segmentation(seg, instance: int, views: tuple[DepthView, ...] = (),
                              target: np.ndarray | None = None, labels=None) -> GraspRequest:
    """The request for ``instance`` of a ``pipeline.Segmentation`` (its whole fused cloud, support included).

    ``target``: an explicit (N,) bool target mask instead of ``seg.instance == instance``
    (e.g. ground-truth labels in the benchmark).
    ``labels``: the run's labelling at step 0 (``update.run_labels.StepZeroLabels``, its correction
    log's edits): ``instance`` is then one of its ids (a deleted or merged id is one clear
    ``SceneError`` saying so) and the target is its points before the contact rule. None: the run's
    own ids, as segmented.
    """
    k = int(instance)
    if target is None and labels is not None:
        if len(labels.geometry) != len(seg.points):
            raise SceneError(f"the labelling has {len(labels.geometry)} points, the run {len(seg.points)}")
        target = labels.target(k)
    elif target is None:
        if not 0 <= k < seg.num_instances:
            raise SceneError(f"instance {k} does not exist: the run has instances 0..{seg.num_instances - 1}")
        # the instance's geometry (``update.geometry.run_geometry``: with its contact to the support,
        # its weak echoes and the fill's points): the trimming rules are for the reported labels; the
        # planner must not count the target's own lowest millimetres as foreign (strict-iou.md, session 8)
        from clutt3r_core.update.geometry import run_geometry

        target = run_geometry(seg) == k
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


def request_from_run(run_dir: str | Path, instance: int, scene: str | Path | None = None, step: int | None = None):
    """(request, segmentation, warning) for ``instance`` of the run in ``run_dir``.

    When the run has updates (``RUN/updates``), the request is in the scene after ``step`` of them
    (None: the latest; 0: the run as segmented; ``scene_now``), as ``clutt3r grasp`` plans: a
    removed instance is a ``SceneError`` naming the update, the cloud is the updated one, the target
    the instance's points before the contact rule there (``SceneAfter.grasp_target``, as at step 0),
    and there are no depth views (the initial views no longer show the scene). At step 0 the ids are those of
    the run's correction log (``update.run_labels.step_zero_labels``: the Edit tab's ids; a deleted
    or merged id is a ``SceneError`` saying so)."""
    from clutt3r_core.runs import load_run, run_voxel_size
    from clutt3r_core.update.run_labels import step_zero_labels
    from clutt3r_core.update.scene_after import resolve_step

    step = resolve_step(run_dir, step)
    seg = load_run(run_dir)
    if step > 0:
        sa = scene_now(run_dir, step, seg, scene)
        return (sa.grasp_request(instance, voxel_size=run_voxel_size(seg)), seg,
                f"{sa.label}: collision check against the updated cloud")
    labels = step_zero_labels(seg, run_dir)
    labels.check_target(instance)  # before the scene's views load
    views, warn = run_views(run_dir, scene)
    return request_from_segmentation(seg, instance, views, labels=labels), seg, warn


def scene_now(run: str | Path, step: int | None, seg=None, scene: str | Path | None = None):
    """The run's ``update.scene_after.SceneAfter`` at ``step`` (None: the latest); the added
    instances' normals face the camera of the post view that added them
    (``update.scene_after.post_eyes``: the one place the query and the grasp find it)."""
    from clutt3r_core.update.scene_after import post_eyes, resolve_step, scene_after

    step = resolve_step(run, step)
    return scene_after(run, step, seg=seg, eyes=post_eyes(run, step, scene))
