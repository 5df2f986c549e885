"""The Updates tab: post-interaction frames (shown only when a loader provides some)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel, downscale_step

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["UpdatesPanel"]

INITIAL = "_-1 = the initial segmentation_"


class UpdatesPanel(Panel):
    tab = "Updates"
    frame: "viser.GuiSliderHandle[int]"
    text: "viser.GuiMarkdownHandle"
    image: "viser.GuiImageHandle | None" = None

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return len(app.data.updates) > 0

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.frame = gui.add_slider("Update frame", -1, len(s.app.data.updates) - 1, 1, -1)
        self.frame.on_update(lambda ev: self.set_update(s, int(self.frame.value)))
        self.text = gui.add_markdown(INITIAL)

    def set_update(self, s: "Session", u: int) -> None:
        with s.lock:
            if u == s.state.update:
                return
            s.state.update = int(u)
            if any(f.point_instance is not None for f in s.app.data.updates):
                s.state.color_mode = "update"
            s.changed(Change.COLOUR)

    def refresh(self, s: "Session", change: Change) -> None:
        if not change & Change.COLOUR:
            return
        ups = s.app.data.updates
        u = s.state.update
        if int(self.frame.value) != u:
            self.frame.value = u
        if not 0 <= u < len(ups):
            self.text.content = INITIAL
            return
        upd = ups[u]
        self.text.content = f"**frame {upd.frame}**  \n{upd.text}"
        if upd.rgb is not None:
            step = downscale_step(upd.rgb.shape[1], IMAGE_MAX_WIDTH)
            if self.image is None:
                assert self.tab_handle is not None
                with self.tab_handle:
                    self.image = s.client.gui.add_image(upd.rgb[::step, ::step], format="jpeg")
            else:
                self.image.image = upd.rgb[::step, ::step]
