"""The Edit tab: merge, split off, delete and name instances of the run (``clutt3r_viewer.edit``)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from clutt3r_core.annotations import Delete, Merge, SetCategory, Split
from clutt3r_viewer.data import node_label
from clutt3r_viewer.edit import instance_option, node_instance_now, node_supervoxels, option_id, status_text
from clutt3r_viewer.panels.base import Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["EditPanel"]


class EditPanel(Panel):
    """Shown when the run folder's corrections are open (``ViewerApp.annotations``)."""

    tab = "Edit"
    md: "viser.GuiMarkdownHandle"
    inst: "viser.GuiDropdownHandle[str]"
    into: "viser.GuiDropdownHandle[str]"
    merge: "viser.GuiButtonHandle"
    split: "viser.GuiButtonHandle"
    delete: "viser.GuiButtonHandle"
    cat: "viser.GuiTextHandle"
    setcat: "viser.GuiButtonHandle"
    undo: "viser.GuiButtonHandle"
    redo: "viser.GuiButtonHandle"
    status: "viser.GuiMarkdownHandle"

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return app.annotations is not None

    def build(self, s: "Session") -> None:
        app = s.app
        gui = s.client.gui
        ann = app.annotations
        self.md = gui.add_markdown("")
        self.inst = gui.add_dropdown("Instance", ["none"], initial_value="none",
                                     hint="the instance to edit; selecting a tree node picks its instance")
        self.inst.on_update(lambda ev: self._pick(s, option_id(self.inst.value)))
        self.into = gui.add_dropdown("Merge into", ["none"], initial_value="none")
        self.merge = gui.add_button("Merge instance into target")
        self.merge.on_click(lambda ev: self._edit(s, lambda k: Merge(into=option_id(self.into.value), other=k)))
        self.split = gui.add_button("Move node's super-voxels to a new instance",
                                    hint="the selected tree node's non-support super-voxels")
        self.split.on_click(lambda ev: self._split(s))
        self.delete = gui.add_button("Delete instance", color="red")
        self.delete.on_click(lambda ev: self._edit(s, lambda k: Delete(k)))
        self.cat = gui.add_text("Category", "")
        self.setcat = gui.add_button("Set category")
        self.setcat.on_click(lambda ev: self._edit(s, lambda k: SetCategory(k, self.cat.value.strip())))
        self.undo = gui.add_button("Undo", icon=None)
        self.undo.on_click(lambda ev: app.edit_run(lambda a: a.undo(), s))
        self.redo = gui.add_button("Redo", icon=None)
        self.redo.on_click(lambda ev: app.edit_run(lambda a: a.redo(), s))
        self.status = gui.add_markdown(status_text(ann))
        if ann.readonly:
            for b in (self.merge, self.split, self.delete, self.setcat, self.undo, self.redo):
                b.disabled = True
        self._refresh_all(s)

    # -- actions (viser's thread pool; the session lock is not held while editing) -------

    def _pick(self, s: "Session", k: int) -> None:
        with s.lock:
            s.state.edit_instance = k
            self._refresh_selection(s)

    def _edit(self, s: "Session", make) -> None:
        k = s.state.edit_instance
        if k < 0:
            s.notify("Edit", "pick an instance first")
            return
        s.app.edit_run(lambda a: a.apply_op(make(k)), s)

    def _split(self, s: "Session") -> None:
        i = s.state.node
        if i < 0:
            s.notify("Edit", "select a node in the Tree tab first")
            return
        sv = node_supervoxels(s.app.data, i)
        s.app.edit_run(lambda a: a.apply_op(Split(supervoxels=tuple(sv))), s, select_new=True)

    # -- display -----------------------------------------------------------------------

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.NODE and s.state.node >= 0:
            # a tree node was selected: edit its (corrected) instance
            k = node_instance_now(s.app.data, s.app.annotations.current, s.state.node)
            if k >= 0:
                s.state.edit_instance = k
        if change & (Change.NODE | Change.LABELS):
            self._refresh_all(s)

    def _refresh_all(self, s: "Session") -> None:
        """Options, buttons and status after any edit (any tab's) or selection change."""
        ann = s.app.annotations
        lab = ann.current
        counts = lab.point_counts()
        alive = [int(k) for k in lab.alive]
        opts = [instance_option(lab, k, counts) for k in alive] or ["none"]
        k = s.state.edit_instance
        if k not in alive:
            k = alive[0] if alive else -1
            s.state.edit_instance = k
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
        self._refresh_selection(s)

    def _refresh_selection(self, s: "Session") -> None:
        d = s.app.data
        lab = s.app.annotations.current
        k = s.state.edit_instance
        i = s.state.node
        node = (f"node **{node_label(d.trace, i)}**: {len(node_supervoxels(d, i))} super-voxels"
                if i >= 0 else "_no tree node selected (Tree tab) — needed to move super-voxels_")
        inst = (f"instance **I{k}**" + (f" `{lab.categories[k]}`" if lab.categories[k] else "")
                + f", {int((lab.instance == k).sum())} points, score {lab.scores[k]:.2f}") if k >= 0 else "_no instance_"
        self.md.content = f"{inst}  \n{node}"
        if self.cat.value != (lab.categories[k] if k >= 0 else ""):
            self.cat.value = lab.categories[k] if k >= 0 else ""
        self.split.disabled = s.app.annotations.readonly or i < 0
