"""The title, the view selector and the selected view's image with its mask candidates.

The Candidates selector shows either the run's own candidates (with the run's roles: instance
tint, parents, background, the selected node) or those of any mask generator of the registry
that can be built without arguments (issue 11: "the viewer shows a view's candidates
whichever generator made them"), generated on demand for the selected view in a background
thread and cached per (view, generator) for the session.
"""

from __future__ import annotations

import threading
from typing import TYPE_CHECKING

import numpy as np

from clutt3r_core.scene import MaskCandidates, View
from clutt3r_viewer.data import GREY, PALETTE, ViewerData
from clutt3r_viewer.layers import HIGHLIGHT
from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel, downscale_step

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["ViewsPanel", "overlay_image", "candidates_overlay", "mask_generators", "view_label"]

NO_IMAGES = "_images unknown: pass the scene folder (`--scene`) to see them_"
RUN = "run"  # the Candidates option that shows the run's own candidates


def _outline(mask: np.ndarray) -> np.ndarray:
    """(H, W) bool -> boundary pixels (mask pixels with a 4-neighbour outside)."""
    m = mask
    inner = m.copy()
    inner[1:] &= m[:-1]
    inner[:-1] &= m[1:]
    inner[:, 1:] &= m[:, :-1]
    inner[:, :-1] &= m[:, 1:]
    return m & ~inner


def overlay_image(data: ViewerData, vi: int, selected: int = -1, max_width: int = IMAGE_MAX_WIDTH) -> np.ndarray | None:
    """The image of view ``vi`` with its mask candidates overlaid, downscaled to ``max_width``.

    Leaves are tinted with their instance colour (grey when in none), parents are outlined
    in white, background masks are hatched dark; the selected node is filled yellow.
    Returns None when the scene's images are unknown.
    """
    if not data.views:
        return None
    view = data.views[vi]
    s = downscale_step(view.camera.width, max_width)
    img = view.rgb[::s, ::s].astype(np.float32)
    nodes = data.view_nodes(vi)
    if view.masks is None or len(nodes) == 0:
        return img.astype(np.uint8)
    tr = data.trace
    stack = {int(i): data.node_mask(int(i))[::s, ::s] for i in nodes}
    # large masks first so that small ones stay visible on top
    order = sorted(stack, key=lambda i: -int(stack[i].sum()))
    for i in order:
        m = stack[i]
        if tr.nodes.background[i]:
            hatch = m & ((np.add.outer(np.arange(m.shape[0]), np.arange(m.shape[1])) // 4) % 4 == 0)
            img[hatch] *= 0.7
        elif tr.nodes.is_leaf[i] or data.substituted[i]:
            inst = data.node_instance[i]
            col = PALETTE[inst % len(PALETTE)] if inst >= 0 else GREY
            img[m] = 0.55 * img[m] + 0.45 * col
    for i in order:
        if not tr.nodes.is_leaf[i]:
            img[_outline(stack[i])] = 255
    if selected in stack:
        m = stack[selected]
        img[~m] *= 0.45  # dim the rest so the selection reads at a glance, whatever its colour
        img[m] = 0.4 * img[m] + 0.6 * HIGHLIGHT
        img[_outline(m)] = (0, 0, 0)
    return np.clip(img, 0, 255).astype(np.uint8)


def candidates_overlay(view: View, cands: MaskCandidates, trees=None, max_width: int = IMAGE_MAX_WIDTH) -> np.ndarray:
    """The view's image with candidates that are not the run's (no instances, no roles):
    leaves of their containment forest (``segmentation.trees``, the run's ``trees`` config) tinted
    one palette colour each, parents outlined in white, as the run's overlay draws them."""
    from clutt3r_core.segmentation.trees import TreeConfig, build_instance_tree

    s = downscale_step(view.camera.width, max_width)
    img = view.rgb[::s, ::s].astype(np.float32)
    if len(cands) == 0:
        return img.astype(np.uint8)
    tree = build_instance_tree(cands, view.frame, trees or TreeConfig())
    # candidates under the tree's minimum area are in neither set, as in the run's overlay
    leaves = set(tree.mask_ids[tree.is_leaf].tolist())
    parents = set(tree.mask_ids[~tree.is_leaf].tolist())
    small = cands.masks[:, ::s, ::s]
    order = np.argsort(-small.reshape(len(small), -1).sum(1), kind="stable")  # small ones on top
    for j in order:
        if int(cands.ids[j]) in leaves:
            m = small[j]
            img[m] = 0.55 * img[m] + 0.45 * PALETTE[j % len(PALETTE)]
    for j in order:
        if int(cands.ids[j]) in parents:
            img[_outline(small[j])] = 255
    return np.clip(img, 0, 255).astype(np.uint8)


def mask_generators() -> dict[str, object]:
    """Every registered mask generator that can be built here without arguments, by name
    (``import`` needs a source and ``sam-onnx`` model paths, so they are left out unless a
    plugin makes them buildable)."""
    from clutt3r_core.registry import backend_status, create_backend

    out = {}
    for st in backend_status("mask_generator"):
        if not st.available:
            continue
        try:
            out[st.spec.name] = create_backend("mask_generator", st.spec.name)
        except Exception:  # noqa: BLE001  (any construction failure just means "not offered")
            continue
    return out


def view_label(data: ViewerData, vi: int) -> str:
    return f"{vi}: frame {int(data.trace.frames[vi])}"


class ViewsPanel(Panel):
    """Above the tabs: what the run is, which view is selected, and that view's masks."""

    tab = None
    title: "viser.GuiMarkdownHandle"
    view: "viser.GuiDropdownHandle[str]"
    image: "viser.GuiImageHandle | None" = None
    candidates: "viser.GuiDropdownHandle[str] | None" = None
    generators: "dict[str, object]"
    generated: "dict[tuple[int, str], MaskCandidates]"
    worker: "threading.Thread | None" = None
    gen_lock: "threading.Lock"
    quiet: bool = False  # set while the panel itself sets the selector (viser then calls on_update too)

    def build(self, s: "Session") -> None:
        d = s.app.data
        gui = s.client.gui
        seg, tr = d.seg, d.trace
        self.title = gui.add_markdown(
            f"**{seg.scene_name or 'scene'}** — {seg.num_instances} instances, {len(seg.points):,} points, "
            f"{len(tr.frames)} views, {int(tr.nodes.is_leaf.sum())} leaves, embedder `{tr.embedder}`"
        )
        with gui.add_folder("View"):
            opts = [view_label(d, i) for i in range(len(tr.frames))]
            self.view = gui.add_dropdown("View", opts or ["none"], initial_value=(opts or ["none"])[0])
            self.view.on_update(lambda ev: s.select_view(int(self.view.value.split(":")[0])) if opts else None)
            img = overlay_image(d, s.state.view)
            self.generators, self.generated = {}, {}
            self.gen_lock = threading.Lock()  # one generation at a time (generators need not be thread-safe)
            if img is not None:
                self.generators = mask_generators()
                self.candidates = gui.add_dropdown("Candidates", [RUN, *self.generators], initial_value=RUN)
                self.candidates.on_update(lambda ev: None if self.quiet else self.select_candidates(s, self.candidates.value))
                self.image = gui.add_image(img, label="masks (leaf tint = instance, white = parent, yellow = selected)",
                                           format="jpeg", jpeg_quality=80)
            else:
                gui.add_markdown(s.app.no_images_text or NO_IMAGES)

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.VIEW and len(s.app.data.trace.frames):
            label = view_label(s.app.data, s.state.view)
            if self.view.value != label:
                self.view.value = label
        if self.image is None:
            return
        # another generator's overlay does not show the selected node: redraw on a new view only
        if change & Change.VIEW or (change & Change.NODE and self.source == RUN):
            self._show(s)

    @property
    def source(self) -> str:
        """The selected Candidates option."""
        return self.candidates.value if self.candidates is not None else RUN

    # -- candidates of other generators ------------------------------------------------

    def select_candidates(self, s: "Session", name: str) -> None:
        """Show ``name``'s candidates (``RUN``: the run's own) for the selected view."""
        with s.lock:
            self._set_source(name)
            self._show(s)

    def _set_source(self, name: str) -> None:
        if self.candidates is not None and self.candidates.value != name:
            self.quiet = True
            try:
                self.candidates.value = name
            finally:
                self.quiet = False

    def _show(self, s: "Session") -> None:
        """Draw the selected source's candidates; start their generation when not cached
        (meanwhile the view shows the run's own, labelled so). Call with ``s.lock`` held."""
        name, vi = self.source, s.state.view
        cands = None if name == RUN else self.generated.get((vi, name))
        if cands is None:
            self.image.image = overlay_image(s.app.data, vi, s.state.node)
            self.image.label = ("masks (leaf tint = instance, white = parent, yellow = selected)" if name == RUN
                                else f"the run's masks while {name} candidates are generated")
            if name != RUN and (self.worker is None or not self.worker.is_alive()):
                self.worker = threading.Thread(target=self._generate, args=(s, vi, name), daemon=True)
                self.worker.start()
            return  # _generate draws them (or the next selection does) once they exist
        view = s.app.data.views[vi]
        self.image.image = candidates_overlay(view, cands, s.app.data.trace.config.trees)
        self.image.label = f"{name} candidates ({len(cands)}; leaf tint = one per leaf, white = parent)"

    def _generate(self, s: "Session", vi: int, name: str) -> None:
        view = s.app.data.views[vi]
        note = s.client.add_notification(
            "Candidates", f"generating {name} candidates for view {vi} (frame {view.frame})…",
            loading=True, with_close_button=False)
        try:
            with self.gen_lock:
                cands = self.generators[name].generate(view)
            body = f"{name}: {len(cands)} candidates for view {vi}"
        except Exception as e:  # noqa: BLE001  (a generator's failure is shown, never kills the viewer)
            cands, body = None, f"{name} failed on view {vi}: {e}"
        note.body, note.loading, note.with_close_button, note.auto_close_seconds = body, False, True, 4.0
        with s.lock:
            if getattr(s, "closed", False):
                return
            if cands is None:  # back to the run's own, so the selector says what is shown
                self._set_source(RUN)
            else:
                self.generated[(vi, name)] = cands
            self.worker = None
            # the selection may have moved on meanwhile: draw what is selected now (and start
            # the next generation it needs)
            if self.image is not None:
                self._show(s)
