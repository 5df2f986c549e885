"""The Updates tab: post-interaction frames (shown only when a loader provides some).

Choosing an update shows the scene after it: the cloud's displaced instances move to their
updated poses (their ``T_world`` composed along the chain) and removed instances turn pale
where they were last seen (colour layer "update", ``update_sources.UpdateSceneLayer``). The
"After the update" checkbox switches to the scene just before it (after the previous update),
so the two can be compared in place. Instances an update added (status "new") are not in the
run's cloud: they are drawn as a second point cloud ("/updates/added", ``update_sources.added_points``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.panels.base import IMAGE_MAX_WIDTH, Change, Panel, downscale_step

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["UpdatesPanel", "update_positions"]

INITIAL = "_-1 = the initial segmentation_"
AFTER = "_the scene **after** this update: displaced instances moved to their new poses, removed ones pale_"
BEFORE = "_the scene **before** this update (after the previous one)_"


def update_positions(s: "Session") -> np.ndarray | None:
    """(M, 3) world positions of the displayed points (``s.lod_idx``) in the Updates tab's scene
    (the Scene panel moves the cloud there), or None outside it (the run's own positions)."""
    if s.state.color_mode != "update" or not 0 <= s.state.update < len(s.app.data.updates):
        return None
    from clutt3r_viewer.panels.update_sources import updated_scene

    return updated_scene(s.app.data, s.state.update, s.lod_idx, s.state.update_after)[0]


class UpdatesPanel(Panel):
    tab = "Updates"
    frame: "viser.GuiSliderHandle[int]"
    after: "viser.GuiCheckboxHandle"
    text: "viser.GuiMarkdownHandle"
    image: "viser.GuiImageHandle | None" = None
    added: "viser.PointCloudHandle | None" = None
    """The instances the shown updates added (status "new"): not in the run's cloud (update_sources.added_points)."""

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
        self.text = gui.add_markdown(INITIAL)

    def _show(self, s: "Session") -> None:
        if any(f.point_instance is not None for f in s.app.data.updates):
            s.state.color_mode = "update"
        s.changed(Change.COLOUR)

    def set_update(self, s: "Session", u: int) -> None:
        with s.lock:
            if u == s.state.update:
                return
            s.state.update = int(u)
            self._show(s)

    def set_after(self, s: "Session", after: bool) -> None:
        """Show the scene after (True) or just before (False) the chosen update."""
        with s.lock:
            if after == s.state.update_after and s.state.color_mode == "update":
                return
            s.state.update_after = bool(after)
            self._show(s)

    def refresh(self, s: "Session", change: Change) -> None:
        if not change & Change.COLOUR:
            return
        ups = s.app.data.updates
        u = s.state.update
        if int(self.frame.value) != u:
            self.frame.value = u
        if bool(self.after.value) != s.state.update_after:
            self.after.value = s.state.update_after
        self._draw_added(s)
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

    def _draw_added(self, s: "Session") -> None:
        """The added instances of the scene shown (after / before the chosen update), coloured by id."""
        if self.added is not None:
            self.added.remove()
            self.added = None
        u = s.state.update
        if s.state.color_mode != "update" or not 0 <= u < len(s.app.data.updates):
            return
        from clutt3r_viewer.data import label_colors
        from clutt3r_viewer.panels.update_sources import added_points

        pts, inst = added_points(s.app.data, u, s.state.update_after)
        if len(pts):
            centre = s.app.data.centre
            self.added = s.client.scene.add_point_cloud(
                "/updates/added", (pts - centre).astype(np.float32), label_colors(inst), point_size=s.app.point_size,
                point_shape="rounded", position=centre)
