"""The scene a tab shows: the run's cloud after the first ``step`` updates of its chain.

An update (issue 10) moves displaced instances, removes grasped ones and, with depth, adds
instances the run never had (status "new", ``UpdateResult.added``). Every panel shows the same
scene (the Updates tab chooses it: ``SessionState.update`` and ``update_after``), so after a
grasp the added instances are drawn, coloured and selectable in every colour mode, the removed
ones are ghosts where they were last seen, the displaced ones are at their new pose.

``ShownScene`` holds it for the displayed points (``idx``, the level of detail) and the added
instances (which are not in the run's cloud: a second cloud). ``chain_steps`` summarises each
update for the timeline. Pure functions over ``ViewerData``; no viser.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ShownScene", "shown_scene", "scene_step", "StepSummary", "chain_steps", "scene_grasp_request"]


_CACHED_SCENES = 8
"""Scenes ``shown_scene`` keeps per run (least recently built dropped first)."""


def scene_step(update: int, after: bool, n_updates: int) -> int:
    """Updates applied to the scene a tab shows: update ``update`` (0-based, -1 = none) and
    the ones before it when ``after``, else only the ones before it."""
    if not 0 <= update < n_updates:
        return 0
    return update + 1 if after else update


@dataclass(frozen=True, eq=False)
class ShownScene:
    """The run's scene after ``step`` updates, for the displayed points ``idx``.

    Attributes:
        step: updates applied (0 = the initial segmentation).
        idx: (M,) int64 displayed points, indices into ``seg.points``.
        points: (M, 3) float64 world metres: displaced instances at their composed motions.
        instance: (M,) int32 instance of each point then, -1 = none or removed.
        gone: (M,) bool points of instances removed by then (ghosts, where last seen).
        added_points: (A, 3) float64 world metres, the instances the updates added (not removed
            since), moved by the later updates.
        added_instance: (A,) int32 their ids.
        added_colors: (A, 3) uint8 their colours (from the new view).
        present: (K,) int32 instance ids in the scene, ascending (run instances not removed,
            then added ones).
        removed: ids removed by then (run or added), ascending.
        added_in: {added id: frame of the update that added it}.
    """

    step: int
    idx: np.ndarray
    points: np.ndarray
    instance: np.ndarray
    gone: np.ndarray
    added_points: np.ndarray
    added_instance: np.ndarray
    added_colors: np.ndarray
    present: np.ndarray
    removed: tuple[int, ...]
    added_in: dict

    def __post_init__(self) -> None:
        m, a = len(self.idx), len(self.added_points)
        if self.points.shape != (m, 3) or self.instance.shape != (m,) or self.gone.shape != (m,):
            raise ValueError(f"ShownScene: points (M,3), instance (M,) and gone (M,) for M = {m} points")
        if self.added_instance.shape != (a,) or self.added_colors.shape != (a, 3):
            raise ValueError(f"ShownScene: added_instance (A,) and added_colors (A,3) for A = {a} points")

    @property
    def moved(self) -> bool:
        return self.step > 0

    def is_added(self, k: int) -> bool:
        return int(k) in self.added_in


def shown_scene(data, step: int, idx: np.ndarray) -> ShownScene:
    """The scene after the first ``step`` updates of ``data.updates`` for points ``idx``
    (cached per (step, displayed point count): the level of detail fixes ``idx``)."""
    from clutt3r_viewer.panels.update_sources import added_instances, chain_instance, updated_scene

    step = int(np.clip(step, 0, len(data.updates)))
    idx = np.asarray(idx, np.int64)
    key = ("shown", step, len(idx))
    hit = data._cache.get(key)
    if hit is not None and np.array_equal(hit.idx, idx):
        return hit
    # a few scenes only: each holds (M, 3) float64 positions (24 MB at 1M points), and tabs
    # step through a chain of updates at one or two levels of detail
    keys = data._cache.setdefault("shown_keys", [])
    if key in keys:
        keys.remove(key)
    while len(keys) >= _CACHED_SCENES:
        data._cache.pop(keys.pop(0), None)
    keys.append(key)
    seg = data.seg
    if step == 0:
        pts = np.asarray(seg.points, np.float64)[idx]
        inst = np.asarray(seg.instance, np.int32)[idx]
        gone = np.zeros(len(idx), bool)
    else:  # updated_scene's (u, after=True) is the scene after u + 1 updates
        pts, inst, gone = updated_scene(data, step - 1, idx, True)
    apts, ainst, acol, added_in = added_instances(data, step)
    removed = sorted({r.instance for u in data.updates[:step] if u.result is not None
                      for r in u.result.instances if r.status == "removed"})
    ids = np.arange(seg.num_instances, dtype=np.int32)
    if step > 0:  # the ids of the labelling the chain was computed from (the Edit tab's corrections then)
        i0 = chain_instance(data)
        if not np.array_equal(i0, seg.instance):  # as update.scene_after: its ids with points
            ids = np.unique(i0[i0 >= 0])
    run_ids = np.setdiff1d(ids, removed)
    present = np.union1d(run_ids, np.unique(ainst)).astype(np.int32)
    out = ShownScene(step, idx, pts, np.asarray(inst, np.int32), gone, apts, ainst, acol, present,
                     tuple(int(x) for x in removed), added_in)
    data._cache[key] = out
    return out


@dataclass(frozen=True)
class StepSummary:
    """What one update of the chain did (the Updates tab's timeline).

    Attributes:
        step: 1-based position in the chain.
        frame: the post-interaction frame.
        removed, added, occluded: instance ids.
        displaced: (id, translation in metres of the instance's centroid, rotation in degrees).
    """

    step: int
    frame: int
    removed: tuple[int, ...]
    displaced: tuple[tuple[int, float, float], ...]
    added: tuple[int, ...]
    occluded: tuple[int, ...]


def chain_steps(data) -> tuple[StepSummary, ...]:
    """One ``StepSummary`` per update of ``data.updates`` (empty records for an update known only
    by its image). A displaced instance's translation is measured at its centroid in the scene
    before that update (``T_world`` also turns it about the world origin, which is not a motion
    of the object). Cached on ``data``."""
    hit = data._cache.get("chain_steps")
    if hit is not None:
        return hit
    out = []
    for j, u in enumerate(data.updates):
        res = u.result
        if res is None:
            out.append(StepSummary(j + 1, u.frame, (), (), (), ()))
            continue
        before = shown_scene(data, j, np.arange(len(data.seg.points)))
        disp = []
        for r in res.instances:
            if r.status != "displaced" or r.T_world is None:
                continue
            T = np.asarray(r.T_world, np.float64)
            sel = before.instance == r.instance
            p = before.points[sel] if sel.any() else before.added_points[before.added_instance == r.instance]
            c = p.mean(axis=0) if len(p) else np.zeros(3)
            move = float(np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - c))
            ang = float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1.0, 1.0))))
            disp.append((r.instance, move, ang))
        out.append(StepSummary(j + 1, u.frame, res.by_status("removed"), tuple(disp), res.by_status("new"),
                               res.by_status("occluded")))
    data._cache["chain_steps"] = tuple(out)
    return data._cache["chain_steps"]


def scene_grasp_request(data, step: int, k: int, knn: int = 16):
    """A ``GraspRequest`` for instance ``k`` of the scene after ``step`` updates: the run's points
    (displaced ones moved, their normals turned with them, removed ones left out) plus the added
    instances' points (by id), whose normals are PCA normals (``knn`` neighbours) of their points
    where they are now, oriented towards the camera of the update that added them moved like the
    object since: as ``clutt3r grasp`` builds it (``update.scene_after``), so the Grasps tab plans
    what the command plans. No depth views: the initial views no longer show the updated scene (a
    cloud-only collision check; the Grasps tab says so)."""
    from clutt3r_core.errors import SceneError
    from clutt3r_core.grasping import GraspRequest
    from clutt3r_core.grasping.request import run_voxel_size
    from clutt3r_core.update.scene_after import oriented_normals
    from clutt3r_viewer.panels.update_sources import chain_instance, update_motions

    seg = data.seg
    sc = shown_scene(data, step, np.arange(len(seg.points)))
    if int(k) not in set(sc.present.tolist()):
        raise SceneError(f"instance {k} is not in the scene after {step} update(s)")
    keep = ~sc.gone
    inst0 = chain_instance(data)  # the ids the chain's motions name (updated_scene moves the points by them)
    nrm = np.asarray(seg.normals, np.float64).copy()
    M = update_motions(data.updates[:step], seg.num_instances)[step]  # every id of the chain, added ones too
    for i in np.flatnonzero(np.any(M != np.eye(4), axis=(1, 2))):
        sel = inst0 == i
        nrm[sel] = nrm[sel] @ M[i, :3, :3].T
    pts, nrms, inst = [sc.points[keep]], [nrm[keep]], [sc.instance[keep]]
    eye_of = {u.frame: u.camera.T_world_camera[:3, 3] for u in data.updates[:step] if u.camera is not None}
    for a in sorted(sc.added_in):
        # float32, as the core's state stores the moved points: the same kNN (ties included) and normals
        p = sc.added_points[sc.added_instance == a].astype(np.float32).astype(np.float64)
        eye, T = eye_of.get(sc.added_in[a]), M[a]
        if eye is not None:
            eye = T[:3, :3] @ np.asarray(eye, np.float64) + T[:3, 3]
        pts.append(p)
        nrms.append(oriented_normals(p, eye, knn))
        inst.append(np.full(len(p), a, np.int32))
    return GraspRequest(points=np.concatenate(pts).astype(np.float32), normals=np.concatenate(nrms).astype(np.float32),
                        target=np.concatenate(inst) == int(k), instance=int(k), views=(),
                        voxel_size=run_voxel_size(seg))
