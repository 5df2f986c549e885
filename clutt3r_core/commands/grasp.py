"""``clutt3r grasp RUN (QUERY | --instance K) [--json] [--top N] [--base-frame FILE]``: grasps for one instance.

Writes ``RUN/grasps.json`` (the object ``--json`` prints) and ``RUN/grasps.npz`` (the viewer's
Grasps tab). The gripper convention is in docs/conventions.md ("Gripper").

When the run has updates (``clutt3r update``, ``RUN/updates``) the grasp is planned in the scene
after the latest one (``--step K`` picks another; 0 = the run as segmented;
``update.scene_after``): a removed instance is one clear error naming the update that removed it,
a displaced one is grasped at its new pose, an added one is graspable, and the collision check
uses the updated cloud (not the initial depth views, which no longer show the scene). The grasp
file records ``"step"``.

At step 0 the ids are those of the run's correction log (the viewer's Edit tab;
``update.run_labels.step_zero_labels``): ``--instance K`` of a deleted or merged id is one clear
error (a merged one names the id it joined), the target is the corrected instance's points before
the contact rule (a merge: the union of its parts'), and ``grasps.json`` records the log state in
``"corrections"`` (absent for a run without a log: the file is what it always was).

After updates the same holds for the chain (session 9): the target is the instance's points before
the contact rule in the scene after the updates (``SceneAfter.grasp_target``: those the update's
state moved with it), and ``"corrections"`` records the log state the chain was computed from
(its ``state.json`` "labels"; absent when it was computed from the run as segmented).
"""

from __future__ import annotations

import json as _json
import sys
import time
from pathlib import Path

from typing import Annotated

import tyro
from tyro.conf import Positional

from clutt3r_core.grasping.antipodal import AntipodalConfig

__all__ = ["grasp_command"]


def _target_from_query(run: Path, text: str, scene: Path | None, step: int | None = None, seg=None):
    """(instance id, note, the ``query.RunQuery``) for a text query through the language backend
    (clutt3r_core.query); the grasp plans in the query's scene (its ``scene`` after updates, its
    ``labelling`` at step 0), so the id it picked is the one planned, and neither is built twice."""
    from clutt3r_core.errors import Clutt3rError

    hint = "pick the instance by id instead: clutt3r grasp RUN --instance K (ids in the viewer or instances.npz)"
    try:
        from clutt3r_core.query import RunQuery
    except ImportError as e:
        raise Clutt3rError(f"text queries need the language backend ({e}); {hint}") from e
    # Re-raised typed (not SystemExit) so the CLI prints one line with status 2 and --debug works
    # (issue 14); the hint is kept. A damaged run fails earlier, in load_run, naming its file.
    try:
        rq = RunQuery.open(run, scene=scene, progress=True, step=step, seg=seg)
        res = rq.query(text)
    except Clutt3rError as e:
        raise Clutt3rError(f"the query could not be answered: {e}; {hint}") from e
    if res.target is None:
        raise SystemExit(f"clutt3r grasp: the run has no instance for '{text}' to name")
    note = "" if res.confident else f"the query '{text}' matches instance {res.target} only weakly"
    return int(res.target), note, rq


def grasp_command(
    run: Annotated[Positional[Path], tyro.conf.arg(metavar="RUN")],
    query: Annotated[Positional[str], tyro.conf.arg(metavar="QUERY")] = "",
    instance: int | None = None,
    json: bool = False,
    top: int = 10,
    base_frame: Path | None = None,
    scene: Path | None = None,
    planner: str = "",
    config: AntipodalConfig = AntipodalConfig(),
    step: int | None = None,
) -> None:
    """Plan parallel-jaw grasps for one instance of a run (gripper convention: docs/conventions.md).

    Args:
        run: run folder written by `clutt3r segment`.
        query: text naming the target ("the red mug"); needs the language backend. Or use --instance.
        instance: target instance id (0-based, as in instances.npz and the viewer).
        json: print one JSON object on the last line: {"target", "query", "grasps": [...]} best first.
        top: number of grasps to print and write.
        base_frame: file with T_base_world (4x4: .json, .npy or text); grasps also get T_base_gripper.
        scene: the scene folder, when the run does not record it (for the unseen-space check).
        planner: grasp planner backend (default: the registry's default, "antipodal").
        config: settings of the antipodal planner.
        step: with updates (RUN/updates), plan in the scene after this many (default: the latest; 0 = as segmented).
    """
    from rich.console import Console

    from clutt3r_core.grasping import load_base_frame
    from clutt3r_core.grasping.request import request_from_segmentation, run_views, scene_now
    from clutt3r_core.registry import create_backend, default_backend
    from clutt3r_core.runs import load_run, run_voxel_size

    console = Console(stderr=True, soft_wrap=True)
    if (instance is None) == (not query):
        raise SystemExit("clutt3r grasp: give either a QUERY or --instance K (exactly one)")
    if top < 1:
        raise SystemExit(f"clutt3r grasp: --top must be >= 1, got {top}")
    # Typed errors (a damaged run, a bad base frame) are not caught here: the CLI prints them as one
    # line with status 2, and --debug shows the traceback (issue 14).
    T_base_world = load_base_frame(base_frame) if base_frame is not None else None
    from clutt3r_core.update.scene_after import chain_length, resolve_step

    n_updates = chain_length(run)
    step = resolve_step(run, step)  # a bad --step: one clear error before anything loads
    seg = load_run(run)
    notes: list[str] = []
    corrections = None  # the correction log state the target's ids came from (grasps.json "corrections")
    rq = None
    if query:
        instance, note, rq = _target_from_query(run, query, scene, step, seg)
        if note:
            notes.append(note)
    if step > 0:
        sa = rq.scene if rq is not None else scene_now(run, step, seg, scene)
        req = sa.grasp_request(instance, voxel_size=run_voxel_size(seg))  # a removed instance: names its update
        corrections = sa.corrections  # the log state the chain's ids came from (stale or not)
        if sa.stale:  # corrections made after the updates: their ids are the older labelling's
            notes.append(sa.stale)
        console.print(f"{sa.label}: collision check against the updated cloud (the initial depth views no longer "
                      "show the scene)")
    else:
        from clutt3r_core.errors import SceneError
        from clutt3r_core.update.run_labels import step_zero_labels

        # the Edit tab's ids (the correction log's edits in effect), as the query above ranked them
        labels = rq.labelling if rq is not None and rq.labelling is not None else step_zero_labels(seg, run)
        try:
            labels.check_target(instance)
        except SceneError as e:
            raise SystemExit(f"clutt3r grasp: {run}: {e}") from None
        corrections = labels.to_json()
        if n_updates or labels.source.entries:
            console.print(labels.describe() + (" (--step 0)" if n_updates else ""))
        views, warn = run_views(run, scene)
        if warn:
            notes.append(warn)
        req = request_from_segmentation(seg, instance, views, labels=labels)
    name = planner or default_backend("grasp_planner")
    gp = create_backend("grasp_planner", name, **({"config": config} if name == "antipodal" else {}))
    t0 = time.perf_counter()
    gs = gp.plan(req)
    dt = time.perf_counter() - t0
    gs = gs.top(top)
    if gs.message:
        notes.append(gs.message)
    run = Path(run)
    rec_step = step if n_updates else None  # a run without updates writes what it always wrote
    gs.save_json(run / "grasps.json", instance, query or None, T_base_world, rec_step, corrections)
    gs.save_npz(run / "grasps.npz")
    for n in notes:
        console.print(f"[yellow]note:[/] {n}")
    if len(gs) == 0:
        console.print(f"[bold red]no grasp found[/] for instance {instance} ({int(req.target.sum())} points) "
                      f"in {dt:.2f} s; wrote an empty list to {run / 'grasps.json'}")
    else:
        console.print(f"[bold]{len(gs)} grasps[/] for instance {instance} ({int(req.target.sum())} points) "
                      f"by '{gp.name}' in {dt:.2f} s -> {run / 'grasps.json'}, {run / 'grasps.npz'}")
        for k in range(len(gs)):
            p = gs.poses[k]
            console.print(f"  #{k}: score {gs.scores[k]:.3f}  width {gs.widths[k] * 1000:.1f} mm  "
                          f"centre ({p[0, 3]:+.3f}, {p[1, 3]:+.3f}, {p[2, 3]:+.3f}) m  "
                          f"approach ({p[0, 2]:+.2f}, {p[1, 2]:+.2f}, {p[2, 2]:+.2f})")
    if json:
        sys.stdout.write(_json.dumps(gs.to_json(instance, query or None, T_base_world, rec_step, corrections)) + "\n")
        sys.stdout.flush()
