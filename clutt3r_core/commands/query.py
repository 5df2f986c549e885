"""``clutt3r query RUN "the yellow mustard bottle" [--json] [--top K]``: which instance a phrase names.

Prints the ranking (best first) with each instance's reason; with ``--json`` the last line
is one JSON object ``{"query", "ranking": [{"instance", "score"}, ...] (every instance),
"target", "confident", "time_s"}``. Writes the target's points to ``RUN/query_target.npz``
(``points`` (P,3) float32 metres, ``colors`` (P,3) uint8, ``instance``, ``query``,
``confident``) and ``RUN/query_target.ply``; both are removed when the run has no instance.

When the run has updates (``clutt3r update``, ``RUN/updates``) the query is asked of the scene
after the latest one (``--step K`` picks another; 0 = the run as segmented), which the output
names ("scene after update 2 (frame 9)"): removed instances are not ranked, added ones are, and
the target's points are where the object is now. The JSON object and the npz then carry
``step`` (and the JSON ``scene``).

At step 0 (no updates, or ``--step 0``) the ids are those of the run's correction log (the Edit
tab's: ``update.run_labels.step_zero_labels``): deleted and merged ids are not ranked, a merged
instance is ranked once with its parts' evidence, and the target's points are its corrected
points. The output names the log state ("the run as segmented with its corrections (log entry 3, 3 edit(s)
in effect)"); the JSON then has ``step`` 0, ``scene`` and
``corrections`` (entries, edits in effect, SHA-256 of the labels). A run whose log changes no
label is queried exactly as without one.
The first query on a run embeds its masks (progress bar) and caches them in
``RUN/query_cache.npz``.
"""

from __future__ import annotations

import json as _json
import time
from pathlib import Path
from typing import Annotated

import tyro
from tyro.conf import Positional

__all__ = ["query_command", "write_target"]


def write_target(run: Path, seg, res) -> Path | None:
    """Write (or remove, when there is no target) ``query_target.npz`` / ``.ply``; the npz path.
    ``seg``: the ``Segmentation`` or the ``SceneAfter`` queried (its points are where objects are now)."""
    import numpy as np

    from clutt3r_core.io.images import atomic_write_bytes, atomic_write_npz
    from clutt3r_core.query import target_points
    from clutt3r_core.runs import ply_bytes

    npz, ply = run / "query_target.npz", run / "query_target.ply"
    if res.target is None:
        for p in (npz, ply):
            p.unlink(missing_ok=True)
        return None
    pts, cols = target_points(seg, res.target)
    extra = {"step": np.int32(res.step)} if res.scene else {}
    atomic_write_npz(npz, points=pts, colors=cols, instance=np.int32(res.target), query=np.array(res.query),
                     confident=np.bool_(res.confident), **extra)
    atomic_write_bytes(ply, ply_bytes(pts, cols, np.full(len(pts), res.target, np.int32)))
    return npz


def query_command(
    run: Annotated[Positional[Path], tyro.conf.arg(metavar="RUN")],
    text: Annotated[Positional[str], tyro.conf.arg(metavar="TEXT")],
    json: bool = False,
    top: int = 5,
    backend: str | None = None,
    scene: Path | None = None,
    step: int | None = None,
) -> None:
    """Find the instance of a run that a phrase names (offline language backend).

    Args:
        run: run folder written by `clutt3r segment`.
        text: what to look for, e.g. "the yellow mustard bottle".
        json: print one JSON object on the last line (every instance ranked).
        top: instances listed in the human-readable output.
        backend: text embedder (default: the registry's default, "imagenet-minilm").
        scene: the scene folder, when the run does not record it (needed once, to embed the masks).
        step: with updates (RUN/updates), query the scene after this many (default: the latest; 0 = as segmented).
    """
    from rich.console import Console
    from rich.markup import escape

    from clutt3r_core.query import RunQuery, parse_query

    t0 = time.perf_counter()
    err = Console(stderr=True)
    if top < 1:
        raise SystemExit(f"clutt3r query: --top must be >= 1, got {top}")
    # Typed errors (a damaged run, a missing backend) are not caught here: the CLI prints them as
    # one line with status 2, and --debug shows the traceback (issue 14).
    parse_query(text)  # an empty query fails before any model loads
    rq = RunQuery.open(run, backend=backend, scene=scene, progress=True, step=step)
    res = rq.query(text)
    if rq.scene is not None and rq.scene.stale:  # corrections after the updates: say so (stderr, also --json)
        Console(stderr=True, soft_wrap=True).print(escape(rq.scene.stale), style="yellow")
    write_target(Path(run), rq.scene if rq.scene is not None else rq.seg, res)
    total = time.perf_counter() - t0
    if json:
        out = res.to_json()
        out["time_s"] = round(total, 4)
        if rq.labelling is not None:  # step 0 of a corrected run: which correction log state ranked
            out["corrections"] = rq.labelling.to_json()
        print(_json.dumps(out))
        return
    con = Console()
    if res.scene:
        sa = rq.scene
        gone = ", ".join(f"{k} (update {s})" for k, (s, _) in sorted(sa.removed.items()))
        undescribed = sorted(set(sa.added) - set(rq.described))
        con.print(f"{escape(res.scene)}" + (f"; removed, not ranked: {gone}" if gone else "")
                  + (f"; added: {', '.join(map(str, sorted(sa.added)))}" if sa.added else "")
                  + (f"; added but not described (no post view or mask in the scene folder), not ranked: "
                     f"{', '.join(map(str, undescribed))}" if undescribed else ""))
    if res.target is None:
        con.print(f"{run}: the {'scene' if res.scene else 'run'} has no instances")
        return
    verdict = "[green]confident[/]" if res.confident else "[yellow]not confident: nothing matches clearly[/]"
    con.print(f"[bold]{escape(res.query)}[/] -> instance {res.target} ({verdict}); backend {res.backend}, "
              f"{res.time_s * 1e3:.0f} ms query, {total:.1f} s total")
    for rank, i in enumerate(res.ranking[:top], 1):
        con.print(f"  {rank}. instance {i:3d}  score {res.scores[i]:+.2f}  {escape(res.explanations[i].summary())}")
    err.print(f"target points -> {Path(run) / 'query_target.npz'}")
