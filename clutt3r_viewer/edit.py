"""The Edit tab: correct a run's instances in the browser through ``clutt3r_core.annotations``.

One ``Annotations`` per server (the run is shared): an edit from any tab is appended to
``corrections/ops.jsonl`` (fsynced) before it shows, the snapshot is rewritten, and every
tab recolours (colour-only update). Each tab keeps its own selection (``SessionState``).
The pure helpers here need no browser; ``clutt3r_viewer.panels.edit.EditPanel`` holds one tab's widgets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_core.annotations import Annotations, CorrectedLabels, CorrectionLogLocked
from clutt3r_core.errors import SceneError

__all__ = ["open_annotations", "node_supervoxels", "node_instance_now", "instance_option", "option_id",
           "status_text", "run_edit"]


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
    state = "saved" if ann.saved else "logged, snapshot pending"
    ro = " **(read-only: another process is editing this run)**" if ann.readonly else ""
    n = ann.num_edits
    return (f"**{n} edit{'' if n == 1 else 's'}**, {state} — {ann.num_ops} log entries in "
            f"`corrections/ops.jsonl`{ro}")


def run_edit(ann: Annotations, action) -> str | None:
    """Run ``action(ann)`` (an apply_op / undo / redo), then save the snapshot; the error text or None."""
    try:
        action(ann)
    except SceneError as e:
        return str(e)
    ann.save()
    return None
