"""The Explain tab: "Why not?" for two masks and "Why here?" for a super-voxel.

"Why not?": pick two masks (type FRAME:MASK, take the Tree tab's selected node, or click
their points in 3D: Alt+click, with "Alt+click in 3D picks" on masks) and read ``clutt3r_core.explain.
explain_pair`` in words and numbers; "Replay: go to step N" moves the Replay tab to the step
where their fates diverged (and the Replay tab then follows the pair). "Why here?": Alt+click a
point (pick mode super-voxel) or type a super-voxel index and read its tally
(``explain_supervoxel``).

Alt+click, because a plain click belongs to the Edit tab's selection (both would fire: viser
calls every scene click callback whose modifier matches). A 3D click arrives as a world ray
(viser ``scene.on_click``); the point is the front-most
displayed point near the ray (``selection.pick_along_ray``), its super-voxel the run's; the
mask of a clicked point is the mask that occupies that super-voxel most, in the selected
view first (``mask_at_supervoxel``). Every action is a method, so tests drive them without
a browser as well as through it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.data import ViewerData
from clutt3r_viewer.panels.base import Change, Panel
from clutt3r_viewer.panels.replay import ReplayPanel, pair_image

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["ExplainPanel", "mask_at_supervoxel", "as_markdown", "PICK_MODES"]

PICK_MODES = ("nothing", "masks A, B", "super-voxel")


def mask_at_supervoxel(data: ViewerData, k: int, view: int = -1) -> int:
    """The grouped mask (non-background leaf or substituted parent) with the largest
    occupancy o_i(k) of super-voxel k, in ``view`` when one there touches it; -1 = none."""
    tr = data.trace
    n = tr.nodes
    cand = (n.is_leaf | data.substituted) & ~n.background
    occ = np.where(cand, tr.occupancy[:, int(k)], 0.0)
    if view >= 0:
        here = np.where(n.view == view, occ, 0.0)
        if here.max(initial=0.0) > 0:
            return int(np.argmax(here))
    return int(np.argmax(occ)) if occ.max(initial=0.0) > 0 else -1


def as_markdown(text: str) -> str:
    """An explanation's ``text()`` as markdown: first line bold, one line each."""
    lines = text.splitlines()
    if not lines:
        return ""
    out = [f"**{lines[0]}**"] + [("\u2003" + x.strip()) if x.startswith("  ") else x for x in lines[1:]]
    return "  \n".join(out)


def _key(data: ViewerData, i: int) -> str:
    f, m = data.trace.nodes.key(i)
    return f"{f}:{m}"


class ExplainPanel(Panel):
    tab = "Explain"
    mask_a: "viser.GuiTextHandle"
    mask_b: "viser.GuiTextHandle"
    take_a: "viser.GuiButtonHandle"
    take_b: "viser.GuiButtonHandle"
    pick: "viser.GuiDropdownHandle[str]"
    why_not: "viser.GuiButtonHandle"
    answer: "viser.GuiMarkdownHandle"
    image: "viser.GuiImageHandle | None" = None
    jump: "viser.GuiButtonHandle"
    supervoxel: "viser.GuiNumberHandle[int]"
    why_here: "viser.GuiButtonHandle"
    sv_answer: "viser.GuiMarkdownHandle"
    result = None  # the last PairExplanation
    sv_result = None  # the last SupervoxelExplanation
    next_pick: str = "a"  # which mask a 3D click sets next

    @classmethod
    def available(cls, app) -> bool:
        return app.data is not None and len(app.data.trace.nodes) > 0

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        d = s.app.data
        gui.add_markdown("**Why not?** Two masks (FRAME:MASK, as the view image and the Tree tab name them): "
                         "why they did or did not end in one instance.")
        self.mask_a = gui.add_text("Mask A", "")
        self.mask_b = gui.add_text("Mask B", "")
        self.take_a = gui.add_button("A = Tree selection")
        self.take_b = gui.add_button("B = Tree selection")
        self.take_a.on_click(lambda ev: self.take_selected(s, "a"))
        self.take_b.on_click(lambda ev: self.take_selected(s, "b"))
        self.pick = gui.add_dropdown("Alt+click in 3D picks", PICK_MODES, initial_value=PICK_MODES[0])
        self.why_not = gui.add_button("Why not?")
        self.why_not.on_click(lambda ev: self.explain_masks(s, self.mask_a.value, self.mask_b.value))
        self.answer = gui.add_markdown("")
        if d.views:
            self.image = gui.add_image(np.full((8, 8, 3), 255, np.uint8), label="mask A orange, mask B blue",
                                       format="jpeg", jpeg_quality=80, visible=False)
        self.jump = gui.add_button("Replay: go to the divergence", disabled=True)
        self.jump.on_click(lambda ev: self.jump_to_divergence(s))
        gui.add_markdown("**Why here?** A super-voxel's votes per group, coverage, winner and runner-up.")
        self.supervoxel = gui.add_number("Super-voxel", 0, min=0, max=max(len(d.trace.vote.sv_label) - 1, 0), step=1)
        self.why_here = gui.add_button("Why here?")
        self.why_here.on_click(lambda ev: self.explain_supervoxel(s, int(self.supervoxel.value)))
        self.sv_answer = gui.add_markdown("")
        s.client.scene.on_click(modifier="alt")(lambda ev: self.on_scene_click(s, ev.ray_origin, ev.ray_direction))

    # -- actions (server side; the tests call them too) ---------------------------------

    def take_selected(self, s: "Session", which: str) -> None:
        with s.lock:
            i = s.state.node
            if i < 0:
                s.notify("Explain", "select a mask in the Tree tab first")
                return
            (self.mask_a if which == "a" else self.mask_b).value = _key(s.app.data, i)

    def explain_masks(self, s: "Session", a: str, b: str) -> None:
        """Explain masks ``a`` and ``b`` (FRAME:MASK or node index) and show the answer."""
        from clutt3r_core.commands.explain import parse_mask_ref
        from clutt3r_core.errors import SceneError
        from clutt3r_core.explain import explain_pair

        d = s.app.data
        with s.lock:
            try:
                r = explain_pair(d.trace, parse_mask_ref(a.strip()), parse_mask_ref(b.strip()))
            except SceneError as e:
                self.answer.content = f"_{e}_"
                self.result = None
                self.jump.disabled = True
                return
            self.result = r
            with s.client.atomic():
                self.answer.content = as_markdown(r.text())
                self.jump.label = f"Replay: go to step {r.diverge_step}"
                self.jump.disabled = False
                if self.image is not None:
                    img = pair_image(d, (r.a,), (r.b,))
                    if img is not None:
                        self.image.image = img
                    self.image.visible = img is not None

    def explain_supervoxel(self, s: "Session", k: int) -> None:
        from clutt3r_core.errors import SceneError
        from clutt3r_core.explain import explain_supervoxel

        with s.lock:
            try:
                self.sv_result = explain_supervoxel(s.app.data.trace, k)
            except SceneError as e:
                self.sv_answer.content = f"_{e}_"
                return
            if int(self.supervoxel.value) != int(k):
                self.supervoxel.value = int(k)
            self.sv_answer.content = as_markdown(self.sv_result.text())

    def jump_to_divergence(self, s: "Session") -> None:
        rp = s.panel(ReplayPanel)
        if self.result is None or rp is None:
            return
        with s.lock:
            rp.focus = (self.result.a, self.result.b)
            if s.state.replay_source != "grouping":
                rp.set_source(s, "grouping")
            s.state.event = -1  # force the refresh even when the slider already shows that step
            rp.set_event(s, int(self.result.diverge_step))
        s.notify("Explain", f"Replay tab: step {self.result.diverge_step}, where the two masks' fates diverged")

    def on_scene_click(self, s: "Session", origin, direction) -> None:
        """A click in 3D (a world ray): pick the front-most displayed point, then act by pick mode."""
        from clutt3r_viewer.selection import pick_along_ray

        mode = self.pick.value
        if mode == PICK_MODES[0]:
            return
        d = s.app.data
        with s.lock:
            shown = np.zeros(len(d.seg.points), bool)
            shown[s.lod_idx] = True
            # the cloud is drawn at the data's centre offset; points are world metres either way
            p = pick_along_ray(d.seg.points, np.asarray(origin), np.asarray(direction), candidates=shown)
        if p < 0:
            return
        self.pick_point(s, p)

    def pick_point(self, s: "Session", p: int) -> None:
        """Act on point ``p`` (index into the run's points) as a click in the current pick mode."""
        d = s.app.data
        k = int(d.seg.sv_labels[p])
        if self.pick.value == "super-voxel":
            self.explain_supervoxel(s, k)
            return
        i = mask_at_supervoxel(d, k, s.state.view)
        if i < 0:
            with s.lock:
                self.answer.content = f"_no grouped mask covers super-voxel {k} (the clicked point)_"
            return
        with s.lock:
            box = self.mask_a if self.next_pick == "a" else self.mask_b
            box.value = _key(d, i)
            self.next_pick = "b" if self.next_pick == "a" else "a"
            both = self.next_pick == "a"
        if both:
            self.explain_masks(s, self.mask_a.value, self.mask_b.value)

    def refresh(self, s: "Session", change: Change) -> None:
        pass  # the answers stay until the next question
