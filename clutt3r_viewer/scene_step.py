"""The scene a tab shows: the run's cloud after the first ``step`` updates of its chain.

An update (issue 10) moves displaced instances, removes grasped ones and, with depth, adds
instances the run never had (status "new", ``UpdateResult.added``). Every panel shows the same
scene (the Updates tab chooses it: ``SessionState.update`` and ``update_after``), so after a
grasp the added instances are drawn, coloured and selectable in every colour mode, the removed
ones are ghosts where they were last seen, the displaced ones are at their new pose.

``ShownScene`` holds it for the displayed points (``idx``, the level of detail) and the added
instances (which are not in the run's cloud: a second cloud); it is a view of the core's
``update.scene_after.SceneAfter``, built by the core's ``build_scene_after`` from the chain the
viewer loaded, so every tab shows the scene ``clutt3r query`` / ``clutt3r grasp --step`` see.
``chain_steps`` summarises each update for the timeline. Pure functions over ``ViewerData``; no viser.

At step 0 the Query and Grasps tabs read the core's ``update.run_labels.step_zero_labels`` of the
Edit tab's live labels (``step_zero_of``): the ids the Edit tab shows, a merged instance's grasp
target the union of its parts' points before the contact rule, as ``clutt3r query`` / ``clutt3r
grasp`` read the correction log.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ShownScene", "shown_scene", "scene_after_of", "chain_inputs_of", "scene_step", "StepSummary", "chain_steps",
           "scene_grasp_request", "step_zero_of"]


_CACHED_SCENES = 8
"""Scenes ``shown_scene`` keeps per run (least recently built dropped first)."""

_CACHED_AFTER = 3
"""Whole-cloud ``SceneAfter``s ``scene_after_of`` keeps per run (each about 33 bytes a run point:
33 MB at 1M points); the shown scenes are views of them."""


def scene_step(update: int, after: bool, n_updates: int) -> int:
    """Updates applied to the scene a tab shows: update ``update`` (0-based, -1 = none) and
    the ones before it when ``after``, else only the ones before it."""
    if not 0 <= update < n_updates:
        return 0
    return update + 1 if after else update


@dataclass(frozen=True, eq=False)
class ShownScene:
    """The run's scene after ``step`` updates, for the displayed points ``idx``: a view of the
    core's ``SceneAfter`` (``scene_after_of``).

    Attributes:
        step: updates applied (0 = the initial segmentation).
        idx: (M,) int64 displayed points, indices into ``seg.points``.
        points: (M, 3) float32 world metres: displaced instances at their composed motions.
        instance: (M,) int32 instance of each point then, -1 = none or removed.
        gone: (M,) bool points of instances removed by then (ghosts, where last seen).
        last_instance: (M,) int32 the chain's id of each point (the labelling the chain was
            computed from: the corrected ids after Edit-tab corrections); a ghost is drawn in
            its removed instance's colour from it.
        added_points: (A, 3) float32 world metres, the instances the updates added (not removed
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
    last_instance: np.ndarray
    added_points: np.ndarray
    added_instance: np.ndarray
    added_colors: np.ndarray
    present: np.ndarray
    removed: tuple[int, ...]
    added_in: dict

    def __post_init__(self) -> None:
        m, a = len(self.idx), len(self.added_points)
        if self.points.shape != (m, 3) or self.instance.shape != (m,) or self.gone.shape != (m,) \
                or self.last_instance.shape != (m,):
            raise ValueError(f"ShownScene: points (M,3), instance, gone and last_instance (M,) for M = {m} points")
        if self.added_instance.shape != (a,) or self.added_colors.shape != (a, 3):
            raise ValueError(f"ShownScene: added_instance (A,) and added_colors (A,3) for A = {a} points")

    @property
    def moved(self) -> bool:
        return self.step > 0

    def is_added(self, k: int) -> bool:
        return int(k) in self.added_in


def chain_inputs_of(data, step: int):
    """The core's ``ChainInputs`` of the scene after the first ``step`` updates of ``data.updates``
    (the chain the viewer loaded): the run's cloud in the chain's labelling (``chain_instance``),
    each update's record (``HistoryEntry.of_result``), the added instances as the state after
    ``step`` updates holds them (``UpdateFrame.added_now``), the post views' camera centres, and
    the chain's labels before the contact rule (the core's ``run_labels.geometry_labels``, as ``clutt3r grasp
    --step`` reads them: the points an update moved or removed with their instance, the grasp target)."""
    from clutt3r_core.update.scene_after import ChainInputs
    from clutt3r_core.update.state import HistoryEntry
    from clutt3r_viewer.panels.update_sources import chain_instance

    seg, ups = data.seg, list(data.updates[:step])
    inst, ids, n_ids = np.asarray(seg.instance, np.int32), np.arange(seg.num_instances), seg.num_instances
    if step > 0:  # the ids of the labelling the chain was computed from (the Edit tab's corrections then)
        i0 = chain_instance(data)
        if not np.array_equal(i0, inst):  # as update.chain_inputs: its ids with points
            inst, ids, n_ids = i0, np.unique(i0[i0 >= 0]), max(n_ids, int(i0.max(initial=-1)) + 1)
    hist = tuple(HistoryEntry.of_result(u.result, j + 1) if u.result is not None
                 else HistoryEntry(j + 1, int(u.frame), (), (), np.zeros((0, 4, 4))) for j, u in enumerate(ups))
    now = ups[-1].added_now if ups else ()
    cat = lambda xs, shape, dt: np.concatenate(xs) if xs else np.zeros(shape, dt)  # noqa: E731
    return ChainInputs(
        points=seg.points, colors=seg.colors, normals=seg.normals, instance=inst, ids=ids, num_ids=n_ids,
        history=hist, n_updates=len(data.updates), added_points=cat([a.points for a in now], (0, 3), np.float32),
        added_colors=cat([a.colors for a in now], (0, 3), np.uint8),
        added_instance=cat([np.full(len(a.points), a.instance, np.int32) for a in now], 0, np.int32),
        eyes={u.frame: u.camera.T_world_camera[:3, 3] for u in ups if u.camera is not None},
        geometry=_held_geometry(data, ups, inst, hist), corrected_away=ups[0].corrected_away if ups else {})


def _pre_contact(data) -> np.ndarray:
    """The core's ``update.geometry.run_geometry(data.seg)`` (the objects' geometry), computed once per run."""
    pre = data._cache.get("pre_contact")
    if pre is None:
        from clutt3r_core.update.geometry import run_geometry

        pre = data._cache["pre_contact"] = np.asarray(run_geometry(data.seg))
    return pre


def _chain_geometry(data, inst: np.ndarray, corrected: bool | None = None) -> np.ndarray:
    """The core's ``run_labels.geometry_labels`` of the labelling ``inst``, once per labelling (the chain's, the run's).
    ``corrected``: the chain's state was built from a corrected labelling (None: ``inst`` differs from the run's)."""
    from clutt3r_core.update.run_labels import geometry_labels

    hit = data._cache.get("chain_geometry")
    if hit is None or hit[1] != corrected or not (hit[0] is inst or np.array_equal(hit[0], inst)):
        hit = data._cache["chain_geometry"] = (inst, corrected, geometry_labels(data.seg, inst, _pre_contact(data),
                                                                                corrected))
    return hit[2]


def _held_geometry(data, ups, inst: np.ndarray, hist) -> np.ndarray | None:
    """The geometry of the scene after the updates ``ups`` as ``update.chain_inputs`` decides it: the
    core's ``run_labels.geometry_labels`` (corrected when the chain's "labels" record has log entries, as the state's
    step 0 was built), kept only when the state after them holds it (``scene_after.held_geometry``, by
    the digest the loader keeps, ``UpdateFrame.state_rows_sha256``); None: a chain computed by an older
    version keeps the scene it always had (one labelling). At step 0 (no ``ups``) the run's own."""
    if not ups:
        return _chain_geometry(data, inst)
    from clutt3r_core.update.scene_after import held_geometry

    src = ups[0].labels
    geo = _chain_geometry(data, inst, src is not None and src.entries > 0)
    rows = ups[-1].state_rows_sha256
    if rows is None:  # frames not read from a saved chain (no state.npz): nothing to check against
        return geo
    return held_geometry(geo, data.seg, [k for h in hist for k in h.removed], rows)


def scene_after_of(data, step: int):
    """The core's ``SceneAfter`` (``update.scene_after.build_scene_after``) of the scene after the
    first ``step`` updates of ``data.updates``: what ``clutt3r query`` / ``clutt3r grasp --step``
    see. Cached per step (the last ``_CACHED_AFTER``)."""
    from clutt3r_core.update.scene_after import build_scene_after

    step = int(np.clip(step, 0, len(data.updates)))
    cache = data._cache.setdefault("scene_after", {})
    if step not in cache:
        while len(cache) >= _CACHED_AFTER:
            cache.pop(next(iter(cache)))
        cache[step] = build_scene_after(chain_inputs_of(data, step))
    else:
        cache[step] = cache.pop(step)  # most recently used last
    return cache[step]


def shown_scene(data, step: int, idx: np.ndarray) -> ShownScene:
    """The scene after the first ``step`` updates of ``data.updates`` for points ``idx``
    (cached per (step, displayed point count): the level of detail fixes ``idx``)."""
    step = int(np.clip(step, 0, len(data.updates)))
    idx = np.asarray(idx, np.int64)
    key = ("shown", step, len(idx))
    hit = data._cache.get(key)
    if hit is not None and np.array_equal(hit.idx, idx):
        return hit
    # a few scenes only: tabs step through a chain of updates at one or two levels of detail
    keys = data._cache.setdefault("shown_keys", [])
    if key in keys:
        keys.remove(key)
    while len(keys) >= _CACHED_SCENES:
        data._cache.pop(keys.pop(0), None)
    keys.append(key)
    sa = scene_after_of(data, step)
    gone, last = sa.gone[idx], sa.run_instance[idx]
    out = ShownScene(step, idx, sa.run_points[idx], np.where(gone, -1, last), gone, last, sa.added_points,
                     sa.added_instance, sa.added_colors, sa.present, tuple(sorted(sa.removed)),
                     {k: f for k, (_, f) in sa.added.items()})
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
        before = scene_after_of(data, j)  # the whole cloud's (a ShownScene of it would copy it and be cached)
        disp = []
        for r in res.instances:
            if r.status != "displaced" or r.T_world is None:
                continue
            T = np.asarray(r.T_world, np.float64)
            sel = (before.run_instance == r.instance) & ~before.gone
            p = before.run_points[sel] if sel.any() else before.added_points[before.added_instance == r.instance]
            c = p.mean(axis=0) if len(p) else np.zeros(3)
            move = float(np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - c))
            ang = float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1.0, 1.0))))
            disp.append((r.instance, move, ang))
        out.append(StepSummary(j + 1, u.frame, res.by_status("removed"), tuple(disp), res.by_status("new"),
                               res.by_status("occluded")))
    data._cache["chain_steps"] = tuple(out)
    return data._cache["chain_steps"]


def scene_grasp_request(data, step: int, k: int):
    """A ``GraspRequest`` for instance ``k`` of the scene after ``step`` updates: the core's
    ``SceneAfter.grasp_request`` (``scene_after_of``), so the Grasps tab plans what ``clutt3r grasp``
    plans (the target: ``k``'s points before the contact rule, ``SceneAfter.grasp_target``). No
    depth views: the initial views no longer show the updated scene (a cloud-only collision check;
    the Grasps tab says so). ``SceneError`` when ``k`` is not in that scene."""
    from clutt3r_core.runs import run_voxel_size

    return scene_after_of(data, step).grasp_request(k, voxel_size=run_voxel_size(data.seg))


def step_zero_of(data, annotations):
    """The core's ``update.run_labels.StepZeroLabels`` of the run at step 0 with the Edit tab's edits
    as they are now (``annotations``: the app's ``Annotations``, its ``current`` labels; None: the
    run's own ids), what the Query and Grasps tabs rank and plan on before any update. Cached on
    ``data`` for one labelling: every edit (or undo) makes a new ``current`` object, so the next call
    after an edit recomputes, never a stale copy. The labels before the contact rule are computed
    once per run (``update.geometry.run_geometry``)."""
    from clutt3r_core.update.run_labels import step_zero_labels

    pre = _pre_contact(data)
    cur = getattr(annotations, "current", None)
    hit = data._cache.get("step_zero")
    if hit is not None and hit[0] is cur:
        return hit[1]
    z = step_zero_labels(data.seg, annotations=annotations if cur is not None else None, pre=pre)
    data._cache["step_zero"] = (cur, z)  # holds ``cur``: its id is never reused while cached
    return z
