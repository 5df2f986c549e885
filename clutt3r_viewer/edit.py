"""The Edit tab: correct a run's instances in the browser through ``clutt3r_core.annotations``.

One ``Annotations`` per server (the run is shared): an edit from any tab is appended to
``corrections/ops.jsonl`` (fsynced) before it shows, the snapshot is rewritten, and every
tab recolours (colour-only update). Each tab keeps its own selection (``SessionState``).
The pure helpers here need no browser; ``EditPanel`` holds one tab's widgets.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_core.annotations import (
    Annotations,
    CorrectedLabels,
    CorrectionLogLocked,
    Delete,
    Merge,
    SetCategory,
    Split,
)
from clutt3r_core.errors import SceneError

__all__ = ["open_annotations", "node_supervoxels", "node_instance_now", "instance_option", "option_id",
           "status_text", "run_edit", "EditPanel"]


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


class EditPanel:
    """The Edit tab of one browser tab (``Session``); built inside the tab's context."""

    def __init__(self, session) -> None:
        self.s = session
        app = session.app
        gui = session.client.gui
        ann = app.annotations
        self.md = gui.add_markdown("")
        self.inst = gui.add_dropdown("Instance", ["none"], initial_value="none",
                                     hint="the instance to edit; selecting a tree node picks its instance")
        self.inst.on_update(lambda ev: self._pick(option_id(self.inst.value)))
        self.into = gui.add_dropdown("Merge into", ["none"], initial_value="none")
        self.merge = gui.add_button("Merge instance into target")
        self.merge.on_click(lambda ev: self._edit(lambda k: Merge(into=option_id(self.into.value), other=k)))
        self.split = gui.add_button("Move node's super-voxels to a new instance",
                                    hint="the selected tree node's non-support super-voxels")
        self.split.on_click(lambda ev: self._split())
        self.delete = gui.add_button("Delete instance", color="red")
        self.delete.on_click(lambda ev: self._edit(lambda k: Delete(k)))
        self.cat = gui.add_text("Category", "")
        self.setcat = gui.add_button("Set category")
        self.setcat.on_click(lambda ev: self._edit(lambda k: SetCategory(k, self.cat.value.strip())))
        self.undo = gui.add_button("Undo", icon=None)
        self.undo.on_click(lambda ev: app.edit_run(lambda a: a.undo(), session))
        self.redo = gui.add_button("Redo", icon=None)
        self.redo.on_click(lambda ev: app.edit_run(lambda a: a.redo(), session))
        self.status = gui.add_markdown(status_text(ann))
        if ann.readonly:
            for b in (self.merge, self.split, self.delete, self.setcat, self.undo, self.redo):
                b.disabled = True
        self.refresh()

    # -- actions (viser's thread pool; the session lock is not held while editing) -------

    def _pick(self, k: int) -> None:
        with self.s.lock:
            self.s.state.edit_instance = k
            self._refresh_selection()

    def _edit(self, make) -> None:
        k = self.s.state.edit_instance
        if k < 0:
            self.s.notify("Edit", "pick an instance first")
            return
        self.s.app.edit_run(lambda a: a.apply_op(make(k)), self.s)

    def _split(self) -> None:
        d = self.s.app.data
        i = self.s.state.node
        if i < 0:
            self.s.notify("Edit", "select a node in the Tree tab first")
            return
        sv = node_supervoxels(d, i)
        self.s.app.edit_run(lambda a: a.apply_op(Split(supervoxels=tuple(sv))), self.s,
                            select_new=True)

    # -- display -----------------------------------------------------------------------

    def refresh(self) -> None:
        """Options, buttons and status after any edit (any tab's) or selection change."""
        ann = self.s.app.annotations
        lab = ann.current
        counts = lab.point_counts()
        alive = [int(k) for k in lab.alive]
        opts = [instance_option(lab, k, counts) for k in alive] or ["none"]
        k = self.s.state.edit_instance
        if k not in alive:
            k = alive[0] if alive else -1
            self.s.state.edit_instance = k
        cur = opts[alive.index(k)] if k >= 0 else "none"
        self.inst.options = opts
        if self.inst.value != cur:
            self.inst.value = cur
        into_id = option_id(self.into.value)
        others = [o for o, j in zip(opts, alive) if j != k] or ["none"]
        self.into.options = others
        if option_id(self.into.value) != into_id or self.into.value not in others:
            self.into.value = next((o for o in others if option_id(o) == into_id), others[0])
        if not ann.readonly:
            self.undo.disabled = not ann.can_undo
            self.redo.disabled = not ann.can_redo
        self.status.content = status_text(ann)
        self._refresh_selection()

    def _refresh_selection(self) -> None:
        d = self.s.app.data
        lab = self.s.app.annotations.current
        k = self.s.state.edit_instance
        i = self.s.state.node
        from clutt3r_viewer.data import node_label

        node = (f"node **{node_label(d.trace, i)}**: {len(node_supervoxels(d, i))} super-voxels"
                if i >= 0 else "_no tree node selected (Tree tab) — needed to move super-voxels_")
        inst = (f"instance **I{k}**" + (f" `{lab.categories[k]}`" if lab.categories[k] else "")
                + f", {int((lab.instance == k).sum())} points, score {lab.scores[k]:.2f}") if k >= 0 else "_no instance_"
        self.md.content = f"{inst}  \n{node}"
        if self.cat.value != (lab.categories[k] if k >= 0 else ""):
            self.cat.value = lab.categories[k] if k >= 0 else ""
        self.split.disabled = self.s.app.annotations.readonly or i < 0

    def select_node(self, i: int) -> None:
        """A tree node was selected: edit its (corrected) instance."""
        if i >= 0:
            k = node_instance_now(self.s.app.data, self.s.app.annotations.current, i)
            if k >= 0:
                self.s.state.edit_instance = k
        self.refresh()


def run_edit(ann: Annotations, action) -> str | None:
    """Run ``action(ann)`` (an apply_op / undo / redo), then save the snapshot; the error text or None."""
    try:
        action(ann)
    except SceneError as e:
        return str(e)
    ann.save()
    return None
