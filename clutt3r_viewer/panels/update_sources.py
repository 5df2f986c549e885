"""Scene updates (issue 10) in the viewer: the Updates tab's frames and the Replay tab's pose
iterations, read from the run's update chain (``RUN/updates/*``, ``clutt3r_core.update.state``).

Importing this module registers:

- an update loader (``register_update_loader``): one ``UpdateFrame`` per saved update, in
  chain order: the before|after overlay (``overlay.png``, else the scene's image), the frame's
  camera, each run point's instance after the update (-1 once its instance was removed), a
  markdown table of every instance's status and IoU, and the ``UpdateResult`` with the pose
  iterations;
- an event source (``register_event_source``) "scene updates: pose iterations": the pose
  optimisation of every displaced instance, update after update. Step n moves each displaced
  instance's points to its pose at iteration n (instances of one update move together; a
  shorter optimisation holds its last pose), composed with the motions of earlier updates;
  colour = the iteration's total loss.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError
from clutt3r_core.scene import Scene
from clutt3r_core.update import InstanceUpdate, PoseResult, UpdateFrame, UpdateResult
from clutt3r_core.update.state import load_pose_traces, state_dirs
from clutt3r_viewer.events import PoseIterations, register_event_source
from clutt3r_viewer.loading import register_update_loader

__all__ = ["load_update_frames", "update_pose_events"]


def _result(folder: Path, doc: dict, hw: tuple[int, int]) -> UpdateResult:
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
    return UpdateResult(int(doc["frame"]), tuple(recs), (), np.zeros((len(recs), *hw), bool),
                        np.full(hw, -1, np.int32), float(doc.get("time_s", 0.0)))


def _text(doc: dict) -> str:
    f = lambda x: "-" if x is None else f"{x:.2f}"  # noqa: E731
    rows = [f"| {r['instance']} | {r['status']} | {f(r['iou_before'])} | {f(r['iou_after'])} |" for r in doc["instances"]]
    return ("| instance | status | IoU before | IoU after |\n| --- | --- | --- | --- |\n" + "\n".join(rows)
            + f"\n\n{len(doc.get('new_masks', []))} new masks; {doc.get('time_s', 0):.2f} s")


def load_update_frames(run_dir: Path | None, scene: Scene | None) -> tuple[UpdateFrame, ...]:
    """The run's saved updates as ``UpdateFrame``s (module docstring); () without any."""
    if run_dir is None:
        return ()
    dirs = state_dirs(run_dir)
    if not dirs:
        return ()
    instance0 = np.load(Path(run_dir) / "instances.npz")["instance"]
    removed: set[int] = set()
    out = []
    from clutt3r_core.io.images import read_rgb

    for d in dirs:
        try:
            doc = json.loads((d / "update.json").read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise Clutt3rError(f"{d / 'update.json'}: unreadable update ({e})") from None
        frame = int(doc["frame"])
        removed |= {int(r["instance"]) for r in doc["instances"] if r["status"] == "removed"}
        view = None
        if scene is not None:
            try:
                view = scene.view_by_frame(frame)
            except KeyError:
                view = None
        rgb = read_rgb(d / "overlay.png") if (d / "overlay.png").is_file() else (view.rgb if view else None)
        hw = (view.camera.height, view.camera.width) if view is not None else (rgb.shape[:2] if rgb is not None else (1, 1))
        pi = np.where(np.isin(instance0, list(removed)), -1, instance0).astype(np.int32)
        out.append(UpdateFrame(frame=frame, rgb=rgb, camera=view.camera if view else None, point_instance=pi,
                               text=_text(doc), result=_result(d, doc, hw)))
    return tuple(out)


def update_pose_events(data) -> PoseIterations | None:
    """The pose iterations of every update of ``data.updates`` as one event source, or None."""
    ups = [u for u in data.updates if u.result is not None]
    moving = [(u, [r for r in u.result.instances if r.pose is not None]) for u in ups]
    moving = [(u, rs) for u, rs in moving if rs]
    if not moving:
        return None
    seg = data.seg
    n_inst = max(seg.num_instances, 1 + max(r.instance for _, rs in moving for r in rs))
    base = np.tile(np.eye(4), (n_inst, 1, 1))  # accumulated motion of earlier updates
    poses, resid = [base.copy()], [np.full(n_inst, np.nan)]
    for _, rs in moving:
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
        for r in rs:
            if r.status == "displaced":
                base[r.instance] = r.T_world @ base[r.instance]
    moved_ids = sorted({r.instance for _, rs in moving for r in rs})
    inst = np.where(np.isin(seg.instance, moved_ids), seg.instance, -1).astype(np.int64)
    return PoseIterations(instance=inst, poses=np.stack(poses), residual=np.stack(resid),
                          points0=seg.points, name="scene updates: pose iterations",
                          context_rgb=np.asarray(seg.colors, np.uint8))


register_update_loader(load_update_frames)
register_event_source(update_pose_events)


def export_updates_rerun(rec, data, max_points: int = 50_000) -> int:
    """Log the update chain to a rerun recording (called by ``rerun_export.export_rerun``).

    Entities: ``world/updates/points`` the moved instances' points on the timeline
    ``pose_iteration`` (the same steps as the Replay source), ``plots/update/loss/I<k>`` and
    ``plots/update/iou/I<k>`` per displaced instance on that timeline, ``updates/overlay`` the
    before|after overlay and ``log/updates`` the status table on the timeline ``update``.
    Returns the number of pose-iteration steps logged (0 without updates).
    """
    import rerun as rr

    from clutt3r_viewer.data import lod_indices

    for u_i, u in enumerate(data.updates):
        rec.set_time("update", sequence=u_i + 1)
        if u.rgb is not None:
            rec.log("updates/overlay", rr.Image(np.ascontiguousarray(u.rgb)).compress(jpeg_quality=85))
        rec.log("log/updates", rr.TextLog(f"frame {u.frame}\n{u.text}"))
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
