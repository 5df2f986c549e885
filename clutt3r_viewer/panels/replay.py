"""The Replay tab: step through any ordered event source (``clutt3r_viewer.events``).

On the grouping's events, each step's two groups (a merge's ``a`` and ``b``; a substitution's
parent and the leaves it replaced) are highlighted: their points in 3D (orange = a, blue = b,
drawn over the cloud) and their masks in the view images (``pair_image``), with the score
and the stage in the text. ``focus`` (set by the Explain tab) adds where two chosen masks
are at the step.
"""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.data import ViewerData
from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel, downscale_step

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["ReplayPanel", "step_groups", "pair_image", "group_points", "COLOUR_A", "COLOUR_B"]

COLOUR_A = np.array([255, 120, 0], np.uint8)   # orange: the first group / mask
COLOUR_B = np.array([0, 140, 255], np.uint8)   # blue: the second


def step_groups(data: ViewerData, n: int) -> tuple[tuple[int, ...], tuple[int, ...], str] | None:
    """The two groups step ``n`` (1..num_events) joined and its words; None for step 0."""
    tr = data.trace
    g = tr.grouping
    if not 1 <= n <= len(g.events):
        return None
    kind, idx = g.events[n - 1]
    if kind == "merge":
        m = g.merges[idx]
        return m.a, m.b, (f"merging **A** ({len(m.a)} masks, orange) + **B** ({len(m.b)} masks, blue): "
                          f"{m.stage} score {m.score:.3f} (S_spatial {m.spatial:.3f}, S_semantic {m.semantic:.3f}), "
                          f"round {m.round}")
    sub = g.substitutions[idx]
    return (sub.parent,), sub.replaced, (f"substitution: parent **A** (orange) replaces {len(sub.replaced)} "
                                         f"residual leaves **B** (blue), round {sub.round}")


def group_points(data: ViewerData, members: tuple[int, ...]) -> np.ndarray:
    """(N,) bool: points of the object super-voxels that a member mask covers at least
    ``min_coverage`` of (the vote's guard): a few pixels bleeding onto the table do not
    light up the table."""
    tr = data.trace
    occ = tr.occupancy[list(members)].max(axis=0) if len(members) else np.zeros(tr.occupancy.shape[1])
    sv_on = (occ >= max(tr.config.vote.min_coverage, 1e-6)) & ~data.seg.sv_support
    return sv_on[data.seg.sv_labels]


def pair_image(data: ViewerData, a: tuple[int, ...], b: tuple[int, ...],
               max_width: int = IMAGE_MAX_WIDTH) -> np.ndarray | None:
    """The views holding a mask of ``a`` or ``b``, tiled two per row, ``a``'s masks tinted
    orange and ``b``'s blue (the rest dimmed). None when the images are unknown."""
    if not data.views:
        return None
    n = data.trace.nodes
    views = sorted({int(n.view[i]) for i in (*a, *b)})
    if not views:
        return None
    cols = 1 if len(views) == 1 else 2
    tiles = []
    for vi in views:
        v = data.views[vi]
        st = downscale_step(v.camera.width, max_width // cols)
        img = v.rgb[::st, ::st].astype(np.float32) * 0.5
        for members, col in ((a, COLOUR_A), (b, COLOUR_B)):
            for i in members:
                if int(n.view[i]) == vi:
                    m = data.node_mask(int(i))
                    if m is not None:
                        m = m[::st, ::st]
                        img[m] = 0.35 * img[m] * 2 + 0.65 * col
        tiles.append(np.clip(img, 0, 255).astype(np.uint8))
    h = max(t.shape[0] for t in tiles)
    w = max(t.shape[1] for t in tiles)
    pad = [np.pad(t, ((0, h - t.shape[0] + 2), (0, w - t.shape[1] + 2), (0, 0)), constant_values=255) for t in tiles]
    if len(pad) % cols:
        pad.append(np.full_like(pad[0], 255))
    rows = [np.concatenate(pad[r:r + cols], axis=1) for r in range(0, len(pad), cols)]
    return np.concatenate(rows, axis=0)


class ReplayPanel(Panel):
    """A slider over the steps of the selected event source, Play/Pause, and the step's text.

    Moving the slider switches the cloud to the ``replay`` colour layer.
    """

    tab = "Replay"
    source: "viser.GuiDropdownHandle[str] | None" = None  # only when the run has more than one source
    event: "viser.GuiSliderHandle[int]"
    play: "viser.GuiButtonHandle"
    text: "viser.GuiMarkdownHandle"
    step_text: "viser.GuiMarkdownHandle"
    image: "viser.GuiImageHandle | None" = None
    cloud_a: "viser.PointCloudHandle | None" = None
    cloud_b: "viser.PointCloudHandle | None" = None
    focus: tuple[int, int] | None = None  # two nodes the Explain tab follows through the steps

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return len(app.sources) > 0

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        names = [src.name for src in s.app.sources]
        if len(names) > 1:
            self.source = gui.add_dropdown("Events", names, initial_value=s.state.replay_source)
            self.source.on_update(lambda ev: self.set_source(s, self.source.value))
        src = s.replay_source()
        ne = src.num_events if src is not None else 0
        self.event = gui.add_slider("Event", 0, max(ne, 1), 1, 0, disabled=ne == 0)
        self.event.on_update(lambda ev: self.set_event(s, int(self.event.value)))
        self.play = gui.add_button("Play", icon=None)
        self.play.on_click(lambda ev: self.toggle_play(s))
        self.text = gui.add_markdown(src.text(0) if src is not None else "")
        self.step_text = gui.add_markdown("")
        if s.app.data.views:
            self.image = gui.add_image(np.full((8, 8, 3), 255, np.uint8), label="masks of this step (A orange, B blue)",
                                       format="jpeg", jpeg_quality=80, visible=False)

    # -- actions -------------------------------------------------------------------------

    def set_source(self, s: "Session", name: str) -> None:
        with s.lock:
            if name == s.state.replay_source:
                return
            s.state.replay_source = name
            s.state.event = 0
            src = s.replay_source()
            ne = src.num_events if src is not None else 0
            with s.client.atomic():
                self.event.max = max(ne, 1)
                self.event.disabled = ne == 0
                s.state.color_mode = "replay"
                s.changed(Change.COLOUR)

    def set_event(self, s: "Session", n: int) -> None:
        with s.lock:
            if n == s.state.event and s.state.color_mode == "replay":
                return
            s.state.event = int(n)
            s.state.color_mode = "replay"
            s.changed(Change.COLOUR)

    def toggle_play(self, s: "Session") -> None:
        with s.lock:
            s.state.playing = not s.state.playing
            self.play.label = "Pause" if s.state.playing else "Play"
            if s.state.playing:
                src = s.replay_source()
                if src is not None and s.state.event >= src.num_events:
                    self.set_event(s, 0)
                threading.Thread(target=self._play_loop, args=(s,), daemon=True).start()

    def _play_loop(self, s: "Session") -> None:
        while s.state.playing and not s.closed:
            time.sleep(s.app.play_interval)
            with s.lock:
                if not s.state.playing:
                    break
                src = s.replay_source()
                n = s.state.event + 1
                if src is None or n > src.num_events:
                    s.state.playing = False
                    self.play.label = "Play"
                    break
                self.set_event(s, n)

    # -- display -------------------------------------------------------------------------

    def refresh(self, s: "Session", change: Change) -> None:
        if not change & Change.COLOUR:
            return
        n = s.state.event
        if int(self.event.value) != n:
            self.event.value = n
        if self.source is not None and self.source.value != s.state.replay_source:
            self.source.value = s.state.replay_source
        src = s.replay_source()
        self.text.content = src.text(n) if src is not None else ""
        self._highlight(s, n if s.state.color_mode == "replay" and s.state.replay_source == "grouping" else 0)

    def _highlight(self, s: "Session", n: int) -> None:
        """Show step n's two groups (points in 3D, masks in the images); hide them for n = 0."""
        d = s.app.data
        sg = step_groups(d, n)
        words = sg[2] if sg is not None else ""
        if self.focus is not None:
            words += ("  \n" if words else "") + self._focus_text(d, n)
        self.step_text.content = words
        if sg is not None:
            self._dim_cloud(s)
        for which, members, col in (("a", sg[0] if sg else (), COLOUR_A), ("b", sg[1] if sg else (), COLOUR_B)):
            handle = getattr(self, f"cloud_{which}")
            if not members:
                if handle is not None:
                    handle.visible = False
                continue
            on = group_points(d, members)
            idx = s.lod_idx[on[s.lod_idx]]
            pts = (d.seg.points[idx] - d.centre).astype(np.float32)
            if handle is not None:
                handle.remove()
            handle = s.client.scene.add_point_cloud(
                f"/replay/group_{which}", pts, np.tile(col, (len(pts), 1)), point_size=s.app.point_size * 1.3,
                point_shape="rounded", position=d.centre)
            setattr(self, f"cloud_{which}", handle)
        if self.image is not None:
            img = pair_image(d, sg[0], sg[1]) if sg is not None else None
            if img is not None:
                self.image.image = img
            self.image.visible = img is not None

    @staticmethod
    def _dim_cloud(s: "Session") -> None:
        # The step's groups are drawn over the cloud in orange and blue, colours the instance
        # palette also uses: dim the cloud under them (the Scene panel refreshed it just before,
        # panels refresh in PANELS order) so the two groups read at a glance.
        from clutt3r_viewer.panels.scene import ScenePanel

        sp = s.panel(ScenePanel)
        if sp is not None:
            sp.cloud.colors = (np.asarray(sp.cloud.colors, np.float32) * 0.35).astype(np.uint8)

    def _focus_text(self, d: ViewerData, n: int) -> str:
        from clutt3r_core.explain import group_history

        a, b = self.focus
        ha, hb = group_history(d.trace, [a, b])
        cur = lambda h: next((g.group for g in reversed(h) if g.step <= n), ())  # noqa: E731
        ga, gb = cur(ha), cur(hb)
        ka, kb = (f"{d.trace.nodes.key(i)[0]}:{d.trace.nodes.key(i)[1]}" for i in (a, b))
        if ga and ga == gb:
            return f"_explained pair {ka} and {kb}: in one group ({len(ga)} masks)_"
        size = lambda g: f"a group of {len(g)} masks" if g else "no group"  # noqa: E731
        return f"_explained pair: {ka} in {size(ga)}, {kb} in {size(gb)}_"
