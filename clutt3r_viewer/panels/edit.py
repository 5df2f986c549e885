"""The Edit tab: select points in 3D and correct the run's instances (``clutt3r_viewer.edit``).

Selection (per tab, server side; ``clutt3r_viewer.selection`` does the geometry):
click = the front-most visible point under the cursor, grown to its super-voxel (or the
point, or its instance: "Click picks"); Shift + drag a box = the visible points inside it
(the points behind a surface are left out; a plain drag still orbits the camera). A plain
click replaces the selection, Shift + click adds, Ctrl / Cmd + click removes, Ctrl / Cmd +
Shift + drag removes a box. Grow adds the touching super-voxels, Invert and Clear do what they say.
The selection is drawn in the highlight colour over the cloud. Hidden instances (view-only,
never logged) are drawn faint and can neither be picked nor block a pick.

Operations on the selection (each one log entry, one undo): assign to the instance chosen
above, new instance, split (only the points of the instance most of the selection lies in),
merge the instances it touches, delete (to background). Instance operations (merge into,
delete, category, the tree node's super-voxels -> new instance) act on the chosen instance.
Keyboard shortcuts (viser's command palette hotkeys): N new, S split, M merge, A assign,
Delete / Backspace delete, G grow, I invert, Escape clear, H hide the chosen instance,
Ctrl+Z undo, Ctrl+Y redo.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from clutt3r_core.annotations import Delete, Merge, SetCategory, Split
from clutt3r_core.corrections import category_suggestions
from clutt3r_core.errors import SceneError
from clutt3r_viewer.data import node_label
from clutt3r_viewer.edit import (
    instance_option,
    node_instance_now,
    node_supervoxels,
    option_id,
    progress_text,
    selection_op,
    selection_summary,
    status_text,
)
from clutt3r_viewer.layers import HIGHLIGHT
from clutt3r_viewer.panels.base import Change, Panel
from clutt3r_viewer.selection import (
    ScreenCamera,
    expand_to_supervoxels,
    grow,
    pick_along_ray,
    supervoxel_adjacency,
    visible_in_rect,
)

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["EditPanel"]

GHOST = np.array([236, 236, 236], np.uint8)  # hidden instances: near the canvas background
_ADJ: dict[int, np.ndarray] = {}  # id(ViewerData) -> super-voxel adjacency (computed once per run)


class EditPanel(Panel):
    """Shown when the run folder's corrections are open (``ViewerApp.annotations``)."""

    tab = "Edit"
    progress: "viser.GuiMarkdownHandle"
    md: "viser.GuiMarkdownHandle"
    inst: "viser.GuiDropdownHandle[str]"
    into: "viser.GuiDropdownHandle[str]"
    merge: "viser.GuiButtonHandle"
    split: "viser.GuiButtonHandle"
    delete: "viser.GuiButtonHandle"
    cat: "viser.GuiTextHandle"
    suggest: "viser.GuiDropdownHandle[str]"
    setcat: "viser.GuiButtonHandle"
    undo: "viser.GuiButtonHandle"
    redo: "viser.GuiButtonHandle"
    status: "viser.GuiMarkdownHandle"
    sel_md: "viser.GuiMarkdownHandle"
    pick_mode: "viser.GuiDropdownHandle[str]"
    sel_buttons: dict
    hide: "viser.GuiButtonHandle"
    show_all: "viser.GuiButtonHandle"

    def __init__(self) -> None:
        self.sel = np.zeros(0, bool)  # (N,) bool over seg.points: this tab's selection
        self.hidden: set[int] = set()  # instance ids this tab does not show (view-only)
        self.sel_cloud = None
        self.picks = 0  # clicks / boxes handled (tests wait on it)
        self.exported = None  # the last ExportSummary of this tab

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return app.annotations is not None

    def build(self, s: "Session") -> None:
        app = s.app
        gui = s.client.gui
        ann = app.annotations
        self.sel = np.zeros(len(app.data.seg.points), bool)
        self.progress = gui.add_markdown(progress_text(ann))
        self.md = gui.add_markdown("")
        self.inst = gui.add_dropdown("Instance", ["none"], initial_value="none",
                                     hint="the instance to edit / assign to; selecting a tree node picks its instance")
        self.inst.on_update(lambda ev: self._pick(s, option_id(self.inst.value)))
        with gui.add_folder("Selection"):
            self.sel_md = gui.add_markdown("_nothing selected: click a point (Shift adds, Ctrl removes), Shift + drag a box_")
            self.click_selects = gui.add_checkbox(
                "Clicks select", True, hint="off: 3D clicks are left to other tabs (Explain's picking)")
            self.pick_mode = gui.add_dropdown("Click picks", ["super-voxel", "point", "instance"],
                                              initial_value="super-voxel")
            self.sel_buttons = {}
            for label, fn in (("Grow", self._grow), ("Invert", self._invert), ("Clear", self._clear)):
                b = gui.add_button(f"{label} selection")
                b.on_click(lambda ev, fn=fn: fn(s))
                self.sel_buttons[label.lower()] = b
            for kind, label, color in (("assign", "Assign selection to instance", None),
                                       ("new", "Selection to new instance", None),
                                       ("split", "Split selection off its instance", None),
                                       ("merge", "Merge instances in selection", None),
                                       ("delete", "Delete selection (to background)", "red")):
                b = gui.add_button(label, color=color)
                b.on_click(lambda ev, kind=kind: self._selection_op(s, kind))
                self.sel_buttons[kind] = b
        with gui.add_folder("Instance"):
            self.into = gui.add_dropdown("Merge into", ["none"], initial_value="none")
            self.merge = gui.add_button("Merge instance into target")
            self.merge.on_click(lambda ev: self._edit(s, lambda k: Merge(into=option_id(self.into.value), other=k)))
            self.split = gui.add_button("Move node's super-voxels to a new instance",
                                        hint="the selected tree node's non-support super-voxels")
            self.split.on_click(lambda ev: self._split(s))
            self.delete = gui.add_button("Delete instance", color="red")
            self.delete.on_click(lambda ev: self._edit(s, lambda k: Delete(k)))
            self.cat = gui.add_text("Category", "")
            self.suggest = gui.add_dropdown("Used categories", ["-"], initial_value="-",
                                            hint="categories already given in this run; picking one fills Category")
            self.suggest.on_update(lambda ev: self._suggested(s))
            self.setcat = gui.add_button("Set category")
            self.setcat.on_click(lambda ev: self._edit(s, lambda k: SetCategory(k, self.cat.value.strip())))
            self.hide = gui.add_button("Hide instance", hint="view-only, this tab (not logged)")
            self.hide.on_click(lambda ev: self._hide(s))
            self.show_all = gui.add_button("Show all instances")
            self.show_all.on_click(lambda ev: self._show_all(s))
        with gui.add_folder("Export ground truth", expand_by_default=False):
            self.export_to = gui.add_text("Export to", str(ann.run_dir.parent / f"{ann.run_dir.name}_gt"),
                                          hint="a new scene folder (clutt3r export-gt RUN OUT)")
            self.export = gui.add_button("Export ground truth")
            self.export.on_click(lambda ev: self._export(s))
            self.export_md = gui.add_markdown("")
        self.undo = gui.add_button("Undo", icon=None)
        self.undo.on_click(lambda ev: app.edit_run(lambda a: a.undo(), s))
        self.redo = gui.add_button("Redo", icon=None)
        self.redo.on_click(lambda ev: app.edit_run(lambda a: a.redo(), s))
        self.status = gui.add_markdown(status_text(ann))
        if ann.readonly:
            for b in (self.merge, self.split, self.delete, self.setcat, self.undo, self.redo,
                      *(self.sel_buttons[k] for k in ("assign", "new", "split", "merge", "delete"))):
                b.disabled = True
        self._bind_pointer(s)
        self._bind_hotkeys(s)
        self._refresh_all(s)

    def _bind_pointer(self, s: "Session") -> None:
        # viser 1.1 keeps a list of scene pointer callbacks (not one slot): other panels may add theirs
        # a box needs a modifier: a plain drag stays the camera's orbit
        scene = s.client.scene
        for mod, how in ((None, "set"), ("shift", "add"), ("cmd/ctrl", "remove")):
            scene.on_click(modifier=mod)(lambda ev, how=how: self.on_click(s, ev.ray_origin, ev.ray_direction, how))
        for mod, how in (("shift", "add"), ("cmd/ctrl+shift", "remove")):
            scene.on_rect_select(modifier=mod)(
                lambda ev, how=how: self.on_rect(s, ev.screen_min, ev.screen_max, how))

    def _bind_hotkeys(self, s: "Session") -> None:
        gui = s.client.gui
        keys = (("Edit: selection to new instance", "N", None, lambda: self._selection_op(s, "new")),
                ("Edit: split selection off its instance", "S", None, lambda: self._selection_op(s, "split")),
                ("Edit: merge instances in selection", "M", None, lambda: self._selection_op(s, "merge")),
                ("Edit: assign selection to instance", "A", None, lambda: self._selection_op(s, "assign")),
                ("Edit: delete selection", "delete", None, lambda: self._selection_op(s, "delete")),
                ("Edit: delete selection ", "backspace", None, lambda: self._selection_op(s, "delete")),
                ("Edit: grow selection", "G", None, lambda: self._grow(s)),
                ("Edit: invert selection", "I", None, lambda: self._invert(s)),
                ("Edit: clear selection", "escape", None, lambda: self._clear(s)),
                ("Edit: hide instance", "H", None, lambda: self._hide(s)),
                ("Edit: undo", "Z", "cmd/ctrl", lambda: s.app.edit_run(lambda a: a.undo(), s)),
                ("Edit: redo", "Y", "cmd/ctrl", lambda: s.app.edit_run(lambda a: a.redo(), s)))
        self.commands = []
        for label, key, mod, fn in keys:
            try:
                c = gui.add_command(label, hotkey=key, modifier=mod)
            except (AttributeError, TypeError, ValueError):  # an older viser without the command palette
                return
            c.on_trigger(lambda ev, fn=fn: fn())
            self.commands.append(c)

    # -- selection (viser's thread pool) -------------------------------------------------

    def _candidates(self, s: "Session") -> np.ndarray:
        """(N,) bool points that can be picked: not in a hidden instance."""
        inst = s.app.annotations.current.instance
        if not self.hidden:
            return np.ones(len(inst), bool)
        return ~np.isin(inst, list(self.hidden))

    def _combine(self, new: np.ndarray, how: str) -> None:
        if how == "add":
            self.sel = self.sel | new
        elif how == "remove":
            self.sel = self.sel & ~new
        else:
            self.sel = new

    @staticmethod
    def _show_run(s: "Session") -> bool:
        """Edits apply to the run's labels at the run's positions: with an update shown (the
        Updates tab; displaced instances elsewhere, added ones not the run's), show the run
        instead and say so. True when it switched (the pick aimed at the other scene is dropped)."""
        if s.scene_step() == 0:
            return False
        s.set_scene(-1, update_colours=False)
        s.notify("Edit", "the Edit tab corrects the run's segmentation: showing the run (before the updates); "
                         "pick again")
        return True

    def on_click(self, s: "Session", origin, direction, how: str = "set") -> int:
        """A click's world ray: select the front-most visible displayed point, grown by "Click picks".
        Returns the picked point (-1: none; a "set" click on nothing clears). With an update shown,
        shows the run instead (``_show_run``) and picks nothing."""
        if not self.click_selects.value or self._show_run(s):
            return -1
        d = s.app.data
        with s.lock:
            cand = self._candidates(s)
            shown = np.zeros(len(cand), bool)
            shown[s.lod_idx] = True
            i = pick_along_ray(d.seg.points, origin, direction, candidates=cand & shown)
            new = np.zeros(len(cand), bool)
            if i >= 0:
                mode = self.pick_mode.value
                if mode == "instance" and s.app.annotations.current.instance[i] >= 0:
                    new = (s.app.annotations.current.instance == s.app.annotations.current.instance[i]) & cand
                elif mode == "point":
                    new[i] = True
                else:
                    new[i] = True
                    new = expand_to_supervoxels(new, d.seg.sv_labels, cand)
            if i >= 0 or how == "set":
                self._combine(new, how)
            self.picks += 1
            self._refresh_all(s)
        return i

    def on_rect(self, s: "Session", screen_min, screen_max, how: str = "set", camera: ScreenCamera | None = None) -> int:
        """A box on the canvas: the visible points inside it (all points, not only the displayed
        level of detail, so an edit has no gaps). Returns how many it selected (0 and the run shown
        instead when an update was shown, ``_show_run``)."""
        if self._show_run(s):
            return 0
        d = s.app.data
        cam = camera if camera is not None else ScreenCamera.from_viser(s.client.camera)
        with s.lock:
            new = visible_in_rect(d.seg.points, cam, screen_min, screen_max, candidates=self._candidates(s))
            self._combine(new, how)
            self.picks += 1
            self._refresh_all(s)
        return int(new.sum())

    def _grow(self, s: "Session") -> None:
        d = s.app.data
        key = id(d)
        if key not in _ADJ:
            _ADJ.clear()  # one run per server
            _ADJ[key] = supervoxel_adjacency(d.seg.points, d.seg.sv_labels)
        with s.lock:
            self.sel = grow(self.sel, d.seg.sv_labels, _ADJ[key], self._candidates(s))
            self._refresh_all(s)

    def _invert(self, s: "Session") -> None:
        with s.lock:
            self.sel = ~self.sel & self._candidates(s)
            self._refresh_all(s)

    def _clear(self, s: "Session") -> None:
        with s.lock:
            self.sel = np.zeros_like(self.sel)
            self._refresh_all(s)

    def set_selection(self, s: "Session", mask: np.ndarray) -> None:
        """Replace the selection (tests, scripts)."""
        with s.lock:
            self.sel = np.asarray(mask, bool).copy()
            self._refresh_all(s)

    def _hide(self, s: "Session") -> None:
        with s.lock:
            k = s.state.edit_instance
            if k < 0:
                return
            self.hidden.add(k)
            self.sel &= self._candidates(s)
            self.changed_view(s)

    def _show_all(self, s: "Session") -> None:
        with s.lock:
            self.hidden.clear()
            self.changed_view(s)

    def changed_view(self, s: "Session") -> None:
        s.recolor()
        self._refresh_all(s)

    def overlay_colors(self, s: "Session", col: np.ndarray) -> np.ndarray:
        """Hidden instances drawn faint (called by ``Session.point_colors``)."""
        if not self.hidden or s.app.annotations is None:
            return col
        hid = np.isin(s.app.annotations.current.instance[s.lod_idx], list(self.hidden))
        if hid.any():
            col = col.copy()
            col[hid] = GHOST
        return col

    # -- actions (viser's thread pool; the session lock is not held while editing) -------

    def _selection_op(self, s: "Session", kind: str) -> None:
        ann = s.app.annotations
        with s.lock:
            sel, target = self.sel.copy(), s.state.edit_instance

        def action(a):
            # built under the app's edit lock on the labels current then (another tab may have edited)
            return a.apply_op(selection_op(kind, a.base, a.current, sel, target))

        try:
            selection_op(kind, ann.base, ann.current, sel, target)  # a missing selection: say so now
        except SceneError as e:
            s.notify("Edit", str(e))
            return
        s.app.edit_run(action, s, select_new=kind in ("new", "split"))

    def _export(self, s: "Session") -> None:
        from pathlib import Path

        from clutt3r_core.export_gt import export_ground_truth

        ann = s.app.annotations
        out = Path(self.export_to.value.strip()).expanduser()
        self.export_md.content = f"_exporting to `{out}` ..._"
        t = time.perf_counter()
        try:
            with s.app._edit_lock:  # the labels of one moment: no edit lands while exporting
                r = export_ground_truth(ann.run_dir, out, scene=s.app.data.scene_root)
        except SceneError as e:  # Clutt3rError subclasses: one line, no traceback
            self.export_md.content = f"**export failed:** {e}"
            return
        except Exception as e:  # noqa: BLE001 (shown to the user; the server keeps running)
            self.export_md.content = f"**export failed:** {type(e).__name__}: {e}"
            return
        self.export_md.content = (f"exported **{r.num_objects} objects**, {r.labelled_points:,} labelled points, "
                                  f"{len(r.views)} views to `{r.out}` in {time.perf_counter() - t:.1f} s")
        self.exported = r

    def _pick(self, s: "Session", k: int) -> None:
        with s.lock:
            s.state.edit_instance = k
            self._refresh_selection(s)

    def _suggested(self, s: "Session") -> None:
        v = self.suggest.value
        if v and v != "-" and self.cat.value != v:
            self.cat.value = v

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
        """Options, buttons, selection and status after any edit (any tab's) or selection change."""
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
        sugg = list(category_suggestions(lab)) or ["-"]
        if list(self.suggest.options) != sugg:
            self.suggest.options = sugg
        if not ann.readonly:
            self.undo.disabled = not ann.can_undo
            self.redo.disabled = not ann.can_redo
        self.status.content = status_text(ann)
        self.progress.content = progress_text(ann)
        self._refresh_selection(s)
        self._draw_selection(s)

    def _refresh_selection(self, s: "Session") -> None:
        d = s.app.data
        lab = s.app.annotations.current
        k = s.state.edit_instance
        i = s.state.node
        node = (f"node **{node_label(d.trace, i)}**: {len(node_supervoxels(d, i))} super-voxels"
                if i >= 0 else "_no tree node selected (Tree tab) — needed to move its super-voxels_")
        inst = (f"instance **I{k}**" + (f" `{lab.categories[k]}`" if lab.categories[k] else "")
                + f", {int((lab.instance == k).sum())} points, score {lab.scores[k]:.2f}") if k >= 0 else "_no instance_"
        hid = f"  \nhidden: {', '.join(f'I{h}' for h in sorted(self.hidden))}" if self.hidden else ""
        self.md.content = f"{inst}  \n{node}{hid}"
        if self.cat.value != (lab.categories[k] if k >= 0 else ""):
            self.cat.value = lab.categories[k] if k >= 0 else ""
        self.split.disabled = s.app.annotations.readonly or i < 0
        n, summ = selection_summary(lab, self.sel) if self.sel.any() else (0, [])
        if n:
            parts = ", ".join(f"{'none' if j < 0 else f'I{j}'} {c:,}" for j, c in summ[:4])
            self.sel_md.content = f"**{n:,} points selected** ({parts}{', ...' if len(summ) > 4 else ''})"
        else:
            self.sel_md.content = "_nothing selected: click a point (Shift adds, Ctrl removes), Shift + drag a box_"

    def _draw_selection(self, s: "Session") -> None:
        shown = self.sel[s.lod_idx]
        pts = s.app.data.seg.points[s.lod_idx][shown]
        if self.sel_cloud is not None:
            self.sel_cloud.remove()
            self.sel_cloud = None
        if len(pts):
            self.sel_cloud = s.client.scene.add_point_cloud(
                "/edit/selection", pts.astype(np.float32), np.broadcast_to(HIGHLIGHT, pts.shape).copy(),
                point_size=s.app.point_size * 1.3, point_shape="rounded")
        self.last_drawn = time.time()
