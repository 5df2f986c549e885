"""The Updates tab: post-interaction frames (shown only when a loader provides some).

Choosing an update shows the scene after it in EVERY tab and colour mode (``Session.set_scene``,
``clutt3r_viewer.scene_step``): displaced instances at their updated poses (their ``T_world``
composed along the chain), removed instances pale where they were last seen, and the instances
the updates added (status "new") drawn as a second cloud by the Scene panel, coloured and
selectable like the others. The "After the update" checkbox switches to the scene just before
it (after the previous update), so the two can be compared in place. The timeline lists, per
update of the chain, what it removed, displaced (how far, how much it turned) and added; the
step shown is marked. When the run's labels (the Edit tab's corrections) differ from the ones
the chain was computed from, a "Stale" line heads the timeline (``update_sources.stale_text``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel, downscale_step
from clutt3r_viewer.scene_step import StepSummary, chain_steps

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["UpdatesPanel", "timeline_markdown"]

INITIAL = "_-1 = the initial segmentation_"
AFTER = ("_the scene **after** this update (in every tab): displaced instances moved to their new poses, "
         "removed ones pale, added ones drawn_")
BEFORE = "_the scene **before** this update (after the previous one)_"


def _ids(ids) -> str:
    return ", ".join(f"I{k}" for k in ids)


def timeline_markdown(steps: tuple[StepSummary, ...], shown: int) -> str:
    """The chain as markdown, one line per update; ``shown`` = updates applied to the scene shown
    (0 = the initial segmentation), its line marked."""
    mark = lambda n: "▶ " if n == shown else ""  # noqa: E731
    lines = [f"{mark(0)}0 · the run (initial segmentation)"]
    for st in steps:
        parts = []
        if st.removed:
            parts.append(f"removed {_ids(st.removed)}")
        if st.displaced:
            parts.append("displaced " + ", ".join(f"I{k} ({m * 100:.1f} cm, {a:.0f}°)" for k, m, a in st.displaced))
        if st.added:
            parts.append(f"_new_ {_ids(st.added)}")  # italic: bold inside the bold current line would not nest
        if st.occluded:
            parts.append(f"occluded {_ids(st.occluded)}")
        text = f"{mark(st.step)}{st.step} · frame {st.frame}: " + ("; ".join(parts) if parts else "nothing changed")
        lines.append(f"**{text}**" if st.step == shown else text)
    if shown == 0:
        lines[0] = f"**{lines[0]}**"
    return "**Timeline**\n\n" + "  \n".join(lines)


class UpdatesPanel(Panel):
    tab = "Updates"
    frame: "viser.GuiSliderHandle[int]"
    after: "viser.GuiCheckboxHandle"
    text: "viser.GuiMarkdownHandle"
    timeline: "viser.GuiMarkdownHandle"
    image: "viser.GuiImageHandle | None" = None

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return len(app.data.updates) > 0

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.frame = gui.add_slider("Update frame", -1, len(s.app.data.updates) - 1, 1, -1)
        self.frame.on_update(lambda ev: self.set_update(s, int(self.frame.value)))
        self.after = gui.add_checkbox("After the update", initial_value=s.state.update_after,
                                      hint="checked: the scene after the chosen update; unchecked: just before it")
        self.after.on_update(lambda ev: self.set_after(s, bool(self.after.value)))
        self.timeline = gui.add_markdown(self._timeline(s))
        self.text = gui.add_markdown(INITIAL)

    def _timeline(self, s: "Session") -> str:
        from clutt3r_viewer.panels.update_sources import stale_text

        md = timeline_markdown(chain_steps(s.app.data), s.scene_step())
        note = stale_text(s.app.data, s.app.instance_labels())
        return md if note is None else f"**⚠ {note}**\n\n{md}"

    def set_update(self, s: "Session", u: int) -> None:
        s.set_scene(int(u))

    def set_after(self, s: "Session", after: bool) -> None:
        """Show the scene after (True) or just before (False) the chosen update."""
        s.set_scene(s.state.update, bool(after))

    def refresh(self, s: "Session", change: Change) -> None:
        if not change & (Change.COLOUR | Change.SCENE | Change.LABELS):
            return
        ups = s.app.data.updates
        u = s.state.update
        if int(self.frame.value) != u:
            self.frame.value = u
        if bool(self.after.value) != s.state.update_after:
            self.after.value = s.state.update_after
        self.timeline.content = self._timeline(s)
        if not 0 <= u < len(ups):
            self.text.content = INITIAL
            return
        upd = ups[u]
        self.text.content = f"**frame {upd.frame}**  \n{AFTER if s.state.update_after else BEFORE}\n\n{upd.text}"
        if upd.rgb is not None:
            step = downscale_step(upd.rgb.shape[1], IMAGE_MAX_WIDTH)
            if self.image is None:
                assert self.tab_handle is not None
                with self.tab_handle:
                    self.image = s.client.gui.add_image(upd.rgb[::step, ::step], format="jpeg")
            else:
                self.image.image = upd.rgb[::step, ::step]
