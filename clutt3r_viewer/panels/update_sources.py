"""Scene updates (issue 10) in the viewer: the Updates tab's frames and the Replay tab's pose
iterations, read from the run's update chain (``RUN/updates/*``, ``clutt3r_core.update.state``).

Importing this module registers:

- an update loader (``register_update_loader``): one ``UpdateFrame`` per saved update, in
  chain order: the before|after overlay (``overlay.png``, else the scene's image), the frame's
  camera, each run point's instance after the update (-1 once its instance was removed), a
  markdown table of every instance's status and IoU, and the ``UpdateResult`` with the pose
  iterations;
- an event source (``register_event_source``) "scene updates: pose iterations"
  (``UpdatePoseIterations``): the pose optimisation of every displaced instance, update after
  update, in the scene before that update (the instances earlier updates added included). Step n
  moves each displaced instance's points to its pose at iteration n (instances of one update move
  together; a shorter optimisation holds its last pose), composed with the motions of earlier
  updates; colour = the iteration's total loss;
- the colour layer "update" (``register_color_layer``): the Updates tab's scene after (or
  just before) the selected update, from ``scene_step.shown_scene``: instances coloured by id, the points
  of removed instances pale (ghosts, left where they were last seen). Every tab shows that scene
  (``clutt3r_viewer.scene_step``), whatever the colour layer.

The chain's ids are those of the labelling it was computed from (session 7: the run's
corrections at that time, ``update.run_labels``; ``UpdateFrame.instance0``); ``stale_text``
says when the labels shown (the Edit tab's, now) differ from it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError
from clutt3r_core.scene import Scene
from clutt3r_core.update import InstanceUpdate, PoseResult, UpdateFrame, UpdateResult
from clutt3r_core.update.types import NewInstance, NewMask
from clutt3r_core.update.state import load_pose_traces, state_dirs

from clutt3r_viewer.data import label_colors
from clutt3r_viewer.events import PoseIterations, register_event_source
from clutt3r_viewer.layers import GHOST_WHITE, ghost_removed, register_color_layer
from clutt3r_viewer.loading import register_update_loader

__all__ = ["load_update_frames", "update_pose_events", "UpdateSceneLayer", "GHOST_WHITE", "chain_instance",
           "stale_text"]



def _added_now(folder: Path, ids: set[int], mask_of: dict[int, int],
               added: set[int]) -> tuple[tuple[NewInstance, ...], str | None]:
    """(the instances ``ids`` as the state saved in ``folder`` holds them (``UpdateFrame.added_now``;
    ``NewInstance.embedding`` from the state: a query in the run's space ranks them by it), the
    digest of its run rows (``UpdateFrame.state_rows_sha256``; ``added``: every id the chain added
    so far), None without a state.npz)."""
    from clutt3r_core.update.run_labels import labels_sha256
    from clutt3r_core.update.scene_after import state_rows

    if not (folder / "state.npz").is_file():
        return (), None
    with np.load(folder / "state.npz") as z:  # each z[key] reads the array from the archive again
        inst = z["instance"]
        rows = labels_sha256(state_rows(inst, added))
        if not ids:
            return (), rows
        pts, cols, sid, emb = z["points"], z["colors"], z["instance_ids"], z["embeddings"]
    e_of = lambda k: emb[int(np.searchsorted(sid, k))] if emb.shape[1] and k in sid else None  # noqa: E731
    return tuple(NewInstance(k, mask_of.get(k, -1), pts[inst == k], cols[inst == k], e_of(k)) for k in sorted(ids)
                 if np.any(inst == k)), rows


def _result(folder: Path, doc: dict, hw: tuple[int, int], now: tuple[NewInstance, ...]) -> UpdateResult:
    traces = load_pose_traces(folder)
    recs = []
    for r in doc["instances"]:
        k = int(r["instance"])
        T = None if r["T_world"] is None else np.asarray(r["T_world"], float)
        pose = None
        if k in traces and T is not None:
            tr = traces[k]
            pose = PoseResult(T, float(r["iou_before"] or 0.0), float(r["iou_after"] or 0.0), tr,
                              int(tr.stage.max(initial=0)) + 1, 0.0)
        recs.append(InstanceUpdate(k, r["status"], r["iou_before"], r["iou_after"], T, pose=pose))
    # instances the update added (status "new"): their points are in the state it saved, as added
    new_ids = {r.instance for r in recs if r.status == "new"}
    added = tuple(a for a in now if a.instance in new_ids)
    new_masks = tuple(NewMask(int(m["mask"]), int(m.get("area_px", 0)), -1 if m.get("instance") is None
                              else int(m["instance"])) for m in doc.get("new_masks", []))
    return UpdateResult(int(doc["frame"]), tuple(recs), new_masks, np.zeros((len(recs), *hw), bool),
                        np.full(hw, -1, np.int32), float(doc.get("time_s", 0.0)), added=added)


def _text(doc: dict) -> str:
    f = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
    rows = [f"| {r['instance']} | {r['status']} | {f(r['iou_before'])} | {f(r['iou_after'])} |" for r in doc["instances"]]
    # masks that became instances (status "new", views with depth; the Updates tab draws
    # their points, read from the update's state.npz, as a second cloud: ShownScene.added_points)
    added = [m["instance"] for m in doc.get("new_masks", []) if m.get("instance") is not None]
    return ("| instance | status | IoU before | IoU after |\n| --- | --- | --- | --- |\n" + "\n".join(rows)
            + f"\n\n{len(doc.get('new_masks', []))} new masks"
            + (f"; {len(added)} added as instances {added}" if added else "")
            + f"; {doc.get('time_s', 0):.2f} s")


def load_update_frames(run_dir: Path | None, scene: Scene | None) -> tuple[UpdateFrame, ...]:
    """The run's saved updates as ``UpdateFrame``s (module docstring); () without any."""
    if run_dir is None:
        return ()
    dirs = state_dirs(run_dir)
    if not dirs:
        return ()
    from clutt3r_core.update.run_labels import chain_source, run_labels
    from clutt3r_core.update.scene_after import post_camera

    src = chain_source(run_dir)[1]
    away: dict[int, str] = {}
    if src is not None and src.entries > 0:  # the corrected labelling the chain was computed from
        lab0 = run_labels(run_dir, entries=src.entries)
        instance0, away = lab0.instance, dict(lab0.gone)
    else:
        instance0 = np.load(Path(run_dir) / "instances.npz")["instance"]
    instance0 = np.asarray(instance0, np.int32)
    removed: set[int] = set()
    added: set[int] = set()
    mask_of: dict[int, int] = {}  # the mask candidate each added instance came from (the query describes it)
    out = []
    from clutt3r_core.io.images import read_rgb

    for d in dirs:
        try:
            doc = json.loads((d / "update.json").read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise Clutt3rError(f"{d / 'update.json'}: unreadable update ({e})") from None
        frame = int(doc["frame"])
        removed |= {int(r["instance"]) for r in doc["instances"] if r["status"] == "removed"}
        added |= {int(r["instance"]) for r in doc["instances"] if r["status"] == "new"}
        mask_of.update({int(m["instance"]): int(m["mask"]) for m in doc.get("new_masks", [])
                        if m.get("instance") is not None})
        now, rows = _added_now(d, added - removed, mask_of, added)
        view = None
        if scene is not None:
            try:
                view = scene.view_by_frame(frame)
            except KeyError:
                view = None
        rgb = read_rgb(d / "overlay.png") if (d / "overlay.png").is_file() else (view.rgb if view else None)
        # the post view's camera as the update recorded it (since session 8; also for --image
        # updates, which the scene folder has no view of), else the scene's view of the frame
        cam = post_camera(d / "update.json", doc) or (view.camera if view else None)
        hw = (cam.height, cam.width) if cam is not None else (rgb.shape[:2] if rgb is not None else (1, 1))
        pi = np.where(np.isin(instance0, list(removed)), -1, instance0).astype(np.int32)
        out.append(UpdateFrame(frame=frame, rgb=rgb, camera=cam, point_instance=pi,
                               text=_text(doc), result=_result(d, doc, hw, now), instance0=instance0,
                               added_now=now, labels=src, state_rows_sha256=rows, corrected_away=away))
    return tuple(out)


@dataclass(frozen=True, eq=False)
class UpdatePoseIterations(PoseIterations):
    """``PoseIterations`` of the update chain over the run's points AND the instances the updates
    added: ``points0`` (and ``instance``, ``context_rgb``) hold the run's N points, then every
    added instance's points as added (A). Step n replays an update's optimisation in the scene
    before that update: the added instances of the earlier updates (not removed by then) are
    there, moved like the others (an added instance an update displaces moves with its pose).

    Attributes:
        n_run: N, the run's points (the first rows of ``points0``).
        added_from: (A,) int64 index in ``data.updates`` of the update that added each point.
        added_until: (A,) int64 index of the update that removed it (len(updates): never).
        step_update: (T,) int64 index in ``data.updates`` of the update step t replays.
        added_id: (A,) int32 instance id of every added point.
    """

    n_run: int = 0
    added_from: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    added_until: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))
    step_update: np.ndarray = field(default_factory=lambda: np.zeros(1, np.int64))
    added_id: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))

    frames: tuple[int, ...] = ()
    """The frame of every update of the chain (``data.updates`` order), for the step's text."""

    def text(self, n: int) -> str:
        j = int(self.step_update[self._it(n)])
        where = f"update {j + 1} of {len(self.frames)} (frame {self.frames[j]}): " if j < len(self.frames) else ""
        return where + super().text(n)

    def added(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
        """(points (A', 3) float32 world metres, instance (A',) int32, colours (A', 3) uint8) of the
        added instances in step n's scene, or None when there are none."""
        j = int(self.step_update[self._it(n)])
        on = np.flatnonzero((self.added_from < j) & (self.added_until >= j))
        if not len(on):
            return None
        idx = self.n_run + on
        inst = np.asarray(self.added_id, np.int32)[on]
        return self.points(n, idx), inst, self.colors(n, idx)


def update_pose_events(data) -> PoseIterations | None:
    """The pose iterations of every update of ``data.updates`` as one event source
    (``UpdatePoseIterations``), or None when no update optimised a pose."""
    moving = [(j, u, [r for r in u.result.instances if r.pose is not None])
              for j, u in enumerate(data.updates) if u.result is not None]
    moving = [(j, u, rs) for j, u, rs in moving if rs]
    if not moving:
        return None
    seg = data.seg
    adds = [(j, a) for j, u in enumerate(data.updates) if u.result is not None for a in u.result.added]
    gone_at = {r.instance: j for j, u in reversed(list(enumerate(data.updates))) if u.result is not None
               for r in u.result.instances if r.status == "removed"}
    ids = [r.instance for _, _, rs in moving for r in rs] + [a.instance for _, a in adds]
    n_inst = max(seg.num_instances, 1 + max(ids))
    base = np.tile(np.eye(4), (n_inst, 1, 1))  # accumulated motion of earlier updates
    poses, resid, step_update = [base.copy()], [np.full(n_inst, np.nan)], [moving[0][0]]
    done = 0  # updates whose displacements are in base (updates without a pose record move nothing)
    for j, u, rs in moving:
        for v in data.updates[done:j]:  # earlier updates that displaced without a recorded pose
            for r in () if v.result is None else v.result.instances:
                if r.status == "displaced" and r.pose is None and r.T_world is not None:
                    base[r.instance] = np.asarray(r.T_world) @ base[r.instance]
        done = j
        length = max(len(r.pose.trace) for r in rs)
        for t in range(length):
            P = base.copy()
            res = np.full(n_inst, np.nan)
            for r in rs:
                tt = min(t, len(r.pose.trace) - 1)
                P[r.instance] = r.pose.trace.T_world[tt] @ base[r.instance]
                res[r.instance] = r.pose.trace.losses[tt, 0]
            poses.append(P)
            resid.append(res)
            step_update.append(j)
        for r in u.result.instances:
            if r.status == "displaced" and r.T_world is not None:
                base[r.instance] = r.T_world @ base[r.instance]
        done = j + 1
    moved_ids = sorted({r.instance for _, _, rs in moving for r in rs})
    inst = np.where(np.isin(seg.instance, moved_ids), seg.instance, -1).astype(np.int64)
    pts, cols = [np.asarray(seg.points, np.float32)], [np.asarray(seg.colors, np.uint8)]
    a_inst, a_id, a_from, a_until = [inst], [], [], []
    for j, a in adds:
        m = len(a.points)
        pts.append(np.asarray(a.points, np.float32))
        cols.append(np.asarray(a.colors, np.uint8))
        a_inst.append(np.full(m, a.instance if a.instance in moved_ids else -1, np.int64))
        a_id.append(np.full(m, a.instance, np.int32))
        a_from.append(np.full(m, j, np.int64))
        a_until.append(np.full(m, gone_at.get(a.instance, len(data.updates)), np.int64))
    cat = lambda xs, dt: np.concatenate(xs) if xs else np.zeros(0, dt)  # noqa: E731
    return UpdatePoseIterations(
        instance=np.concatenate(a_inst), poses=np.stack(poses), residual=np.stack(resid), points0=np.concatenate(pts),
        name="scene updates: pose iterations", context_rgb=np.concatenate(cols), n_run=len(seg.points),
        added_from=cat(a_from, np.int64), added_until=cat(a_until, np.int64),
        step_update=np.asarray(step_update, np.int64), added_id=cat(a_id, np.int32),
        frames=tuple(int(u.frame) for u in data.updates))


def chain_instance(data) -> np.ndarray:
    """(N,) int32 the labelling the update chain of ``data`` was computed from (its ids): the
    frames' ``instance0``, else the run as segmented."""
    i0 = data.updates[0].instance0 if data.updates else None
    return np.asarray(data.seg.instance if i0 is None else i0, np.int32)


def stale_text(data, labels: np.ndarray) -> str | None:
    """One line when ``labels`` (the run's labels now, e.g. the Edit tab's) differ from the ones
    the update chain was computed from, else None (also without updates)."""
    if not data.updates:
        return None
    from clutt3r_core.update.run_labels import labels_change

    what = labels_change(chain_instance(data), labels)
    if what is None:
        return None
    n = len(data.updates)
    return (f"Stale: the {n} update(s) were computed before the corrections made since ({what}); their ids "
            f"are the older labelling's. Recompute: clutt3r update RUN --frame F --recompute "
            f"(moves RUN/updates aside, deletes nothing)")


@dataclass(frozen=True)
class UpdateSceneLayer:
    """Colour layer "update": instances after (or before, ``SessionState.update_after``) the
    selected update (``SessionState.update``), removed ones pale (``GHOST_WHITE``)."""

    name: str = "update"

    def available(self, inp, state) -> bool:
        return any(u.point_instance is not None for u in inp.data.updates)

    def colors(self, inp, state) -> np.ndarray:
        if not 0 <= state.update < len(inp.data.updates):
            return label_colors(inp.instance[inp.idx])  # -1 = the initial segmentation
        from clutt3r_viewer.scene_step import scene_step, shown_scene

        sc = shown_scene(inp.data, scene_step(state.update, state.update_after, len(inp.data.updates)), inp.idx)
        return ghost_removed(label_colors(sc.instance), sc)


register_update_loader(load_update_frames)
register_event_source(update_pose_events)
register_color_layer(UpdateSceneLayer())


def export_updates_rerun(rec, data, max_points: int = 50_000) -> int:
    """Log the update chain to a rerun recording (called by ``rerun_export.export_rerun``).

    Entities: ``world/updates/points`` the moved instances' points on the timeline
    ``pose_iteration`` (the same steps as the Replay source), ``plots/update/loss/I<k>`` and
    ``plots/update/iou/I<k>`` per displaced instance on that timeline, ``updates/overlay`` the
    before|after overlay, ``log/updates`` the status table and ``world/updates/scene`` the scene
    after each update (``scene_step.shown_scene``: displaced instances moved, removed ones left
    out, added ones in, instance colours; at most ``max_points`` of the run's points) on the
    timeline ``update``. Returns the number of pose-iteration steps logged (0 without updates).
    """
    import rerun as rr

    from clutt3r_viewer.data import label_colors, lod_indices
    from clutt3r_viewer.scene_step import shown_scene

    lod = lod_indices(len(data.seg.points), max_points)
    for u_i, u in enumerate(data.updates):
        rec.set_time("update", sequence=u_i + 1)
        if u.rgb is not None:
            rec.log("updates/overlay", rr.Image(np.ascontiguousarray(u.rgb)).compress(jpeg_quality=85))
        rec.log("log/updates", rr.TextLog(f"frame {u.frame}\n{u.text}"))
        sc = shown_scene(data, u_i + 1, lod)
        keep = ~sc.gone
        rec.log("world/updates/scene", rr.Points3D(
            np.concatenate([sc.points[keep], sc.added_points]).astype(np.float32),
            colors=label_colors(np.concatenate([sc.instance[keep], sc.added_instance])), radii=0.003))
    src = update_pose_events(data)
    if src is None:
        return 0
    moving = np.flatnonzero(src.instance >= 0)
    idx = moving[lod_indices(len(moving), max_points)]
    ups = [u for u in data.updates if u.result is not None]
    rows = []  # (instance, loss, iou) per global step, in the order update_pose_events builds them
    for u in ups:
        rs = [r for r in u.result.instances if r.pose is not None]
        if not rs:
            continue
        for t in range(max(len(r.pose.trace) for r in rs)):
            rows.append([(r.instance, r.pose.trace.losses[min(t, len(r.pose.trace) - 1), 0],
                          r.pose.trace.iou[min(t, len(r.pose.trace) - 1)]) for r in rs])
    for n in range(src.num_events + 1):
        rec.set_time("pose_iteration", sequence=n)
        rec.log("world/updates/points", rr.Points3D(src.points(n, idx), colors=src.colors(n, idx), radii=0.003))
        if n >= 1:
            for k, loss, iou in rows[n - 1]:
                rec.log(f"plots/update/loss/I{k}", rr.Scalars(float(loss)))
                rec.log(f"plots/update/iou/I{k}", rr.Scalars(float(iou)))
    return src.num_events


def update_curves(frame: UpdateFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray, tuple[int, ...]]:
    """The loss and IoU curves of one update's pose optimisations, for plotting.

    Returns (x (T,) float64 iteration index, loss (S, T) total loss, iou (S, T), instance ids
    (S,)), one row per instance that was optimised; a shorter optimisation holds its last
    value. S = 0 when nothing was optimised.
    """
    rs = [] if frame.result is None else [r for r in frame.result.instances if r.pose is not None]
    if not rs:
        return np.zeros(0), np.zeros((0, 0)), np.zeros((0, 0)), ()
    t = max(len(r.pose.trace) for r in rs)
    loss = np.empty((len(rs), t))
    iou = np.empty((len(rs), t))
    for i, r in enumerate(rs):
        tr = r.pose.trace
        idx = np.minimum(np.arange(t), len(tr) - 1)
        loss[i], iou[i] = tr.losses[idx, 0], tr.iou[idx]
    return np.arange(t, dtype=np.float64), loss, iou, tuple(r.instance for r in rs)
