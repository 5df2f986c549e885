"""The Edit tab: correct a run's instances in the browser through ``clutt3r_core.annotations``.

One ``Annotations`` per server (the run is shared): an edit from any tab is appended to
``corrections/ops.jsonl`` (fsynced) before it shows, and every tab recolours (colour-only
update). Edits of all tabs go through ``ViewerApp.edit_run``, one at a time (one lock, one
writer): an edit built on a state another tab changed meanwhile is validated against the
current labels and refused with the reason (never applied to the wrong instance, never
lost). The snapshot is a checkpoint (``Annotations.checkpoint``: every 64 entries or 30 s),
since the log is already durable. Each tab keeps its own selection and hidden instances.
``selection_op`` turns a point selection into the operation a button names.
The pure helpers here need no browser; ``clutt3r_viewer.panels.edit.EditPanel`` holds one tab's widgets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_core.annotations import Annotations, CorrectedLabels, CorrectionLogLocked
from clutt3r_core.errors import SceneError

__all__ = ["open_annotations", "node_supervoxels", "node_instance_now", "instance_option", "option_id",
           "status_text", "progress_text", "run_edit", "selection_op", "SELECTION_OPS", "selection_summary"]


def open_annotations(run_dir: Path, seg, author: str = "") -> Annotations:
    """The run's corrections, writable; read-only when another process holds the log."""
    try:
        return Annotations.open(run_dir, segmentation=seg, author=author)
    except CorrectionLogLocked:
        return Annotations.open(run_dir, segmentation=seg, author=author, readonly=True)


def node_supervoxels(data, i: int) -> np.ndarray:
    """(S,) int64 super-voxels node i occupies (o_i(k) > 0, as highlighted), support ones left out:
    moving a mask to a new instance must not carry the table with it."""
    occ = data.trace.occupancy[int(i)] > 0
    return np.flatnonzero(occ & ~data.seg.sv_support[: len(occ)])


def node_instance_now(data, labels: CorrectedLabels, i: int) -> int:
    """The corrected instance holding most of node i's (non-support) points, -1 if none."""
    sv = node_supervoxels(data, i)
    if len(sv) == 0:
        return -1
    lut = np.zeros(data.trace.occupancy.shape[1], bool)
    lut[sv] = True
    inst = labels.instance[lut[data.seg.sv_labels]]
    inst = inst[inst >= 0]
    return int(np.bincount(inst).argmax()) if len(inst) else -1


def instance_option(labels: CorrectedLabels, k: int, counts: np.ndarray) -> str:
    """Dropdown text of instance k: 'I3 mug (1234 pts)'; the id is the first word."""
    cat = labels.categories[k]
    return f"I{k}" + (f" {cat}" if cat else "") + f" ({int(counts[k])} pts)"


def option_id(text: str | None) -> int:
    """Inverse of ``instance_option`` (-1 for none / unparsable)."""
    try:
        return int(str(text).split()[0][1:])
    except (ValueError, IndexError):
        return -1


def status_text(ann: Annotations) -> str:
    # every entry is fsynced when it is made; the snapshot is only a checkpoint for reopening
    state = "checkpoint up to date" if ann.saved else f"checkpoint at entry {ann.saved_ops}"
    ro = " **(read-only: another process is editing this run)**" if ann.readonly else ""
    n = ann.num_edits
    return (f"**{n} edit{'' if n == 1 else 's'}** — {ann.num_ops} log entries in "
            f"`corrections/ops.jsonl` (each saved at once), {state}{ro}")


def progress_text(ann: Annotations, now: float | None = None) -> str:
    """The progress line: instances labelled (named) / alive, points without an instance, last save."""
    import time

    lab = ann.current
    counts = lab.point_counts()
    alive = [int(k) for k in lab.alive if counts[k] > 0]
    named = sum(1 for k in alive if lab.categories[k])
    unl = int((lab.instance < 0).sum())
    t = ann.last_write
    if t <= 0 and ann.log_path.is_file():  # edits of an earlier session (or of another process)
        t = ann.log_path.stat().st_mtime
    if t <= 0:
        last = "no edit yet"
    else:
        age = (now if now is not None else time.time()) - t
        last = f"last save {time.strftime('%H:%M:%S', time.localtime(t))} ({age:.0f} s ago)"
    return (f"**{named}/{len(alive)} instances labelled**, {unl:,} of {len(lab.instance):,} points unlabelled, "
            f"{last}")


def run_edit(ann: Annotations, action) -> str | None:
    """Run ``action(ann)`` (an apply_op / undo / redo; fsynced to the log before it returns), then
    checkpoint the snapshot when due; the error text or None."""
    try:
        action(ann)
    except SceneError as e:
        return str(e)
    ann.checkpoint()
    return None


SELECTION_OPS = ("assign", "new", "split", "merge", "delete")


def selection_summary(labels: CorrectedLabels, sel: np.ndarray) -> tuple[int, list[tuple[int, int]]]:
    """(points selected, [(instance, points of it in the selection), ...] most first; -1 = none)."""
    inst = labels.instance[sel]
    ids, cnt = np.unique(inst, return_counts=True)
    order = np.argsort(-cnt, kind="stable")
    return int(sel.sum()), [(int(ids[i]), int(cnt[i])) for i in order]


def selection_op(kind: str, base, labels: CorrectedLabels, sel: np.ndarray, target: int = -1):
    """The operation the Edit tab's button ``kind`` applies to the (N,) bool selection ``sel``.

    assign: the selection joins instance ``target``; new: the selection becomes one new
    instance; split: only the points of the instance most of the selection lies in leave it
    for a new instance; merge: every instance the selection touches joins the largest of
    them; delete: the selection goes to background (-1). Raises SceneError with what is missing.
    """
    from clutt3r_core.corrections import BaseLabels, Merge, Relabel, Split, selection_fields

    sel = np.asarray(sel, bool)
    if not sel.any():
        raise SceneError("select points first (click, or drag a box with the rectangle tool)")
    base = BaseLabels.of(base)
    if kind == "merge":
        ids = [k for k in np.unique(labels.instance[sel]) if k >= 0]
        if len(ids) < 2:
            raise SceneError("merge: the selection must touch two instances or more")
        counts = labels.point_counts()
        into = max(ids, key=lambda k: (counts[k], -k))
        rest = [int(k) for k in ids if k != into]
        return Merge(into=int(into), other=rest[0], others=tuple(rest[1:]))
    sv, pts = selection_fields(base, sel)
    if kind == "assign":
        if target < 0:
            raise SceneError("assign: pick the target instance first")
        return Relabel(int(target), supervoxels=sv, points=pts)
    if kind == "delete":
        return Relabel(-1, supervoxels=sv, points=pts)
    if kind == "new":
        return Split(supervoxels=sv, points=pts)
    if kind == "split":
        _, summ = selection_summary(labels, sel)
        src = next((k for k, _ in summ if k >= 0), None)
        if src is None:
            raise SceneError("split: the selection lies in no instance")
        return Split(supervoxels=sv, points=pts, source=int(src))
    raise SceneError(f"unknown selection operation {kind!r} (one of {', '.join(SELECTION_OPS)})")
