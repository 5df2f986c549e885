"""The 3D scene (point cloud, camera frustums, mask centroids) and the Scene tab's display controls."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.camera import frustum_scale
from clutt3r_viewer.data import label_colors, lod_indices
from clutt3r_viewer.layers import available_layers
from clutt3r_viewer.panels.base import Change, Panel, downscale_step

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["ScenePanel", "InstancesPanel", "LOD_OPTIONS"]

LOD_OPTIONS = {"50k": 50_000, "200k": 200_000, "1M": 1_000_000, "all": 0}
_THUMB_MAX_WIDTH = 160  # frustum thumbnails: small, they are only a visual cue
_SELECTED_VIEW = (255, 170, 0)
_OTHER_VIEW = (60, 60, 60)


class ScenePanel(Panel):
    """Owns the cloud (colours via the session's colour layers), the frustums and per-view centroids."""

    tab = "Scene"
    color: "viser.GuiDropdownHandle[str]"
    lod: "viser.GuiDropdownHandle[str]"
    size: "viser.GuiSliderHandle[float]"
    cameras: "viser.GuiCheckboxHandle"
    cloud: "viser.PointCloudHandle"
    frustums: "list[viser.CameraFrustumHandle]"
    centroids: "list[viser.PointCloudHandle]"
    frustum_scale: float = 0.04
    moved: bool = False  # the cloud shows an event source's positions, not the run's

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.color = gui.add_dropdown("Colour", self._layer_names(s), initial_value=s.state.color_mode)
        self.color.on_update(lambda ev: s.set_color_mode(self.color.value))
        self.lod = gui.add_dropdown("Max points", tuple(LOD_OPTIONS), initial_value=s.state.lod,
                                    hint="level of detail: points sent to this tab")
        self.lod.on_update(lambda ev: self.set_lod(s, self.lod.value))
        self.size = gui.add_slider("Point size (mm)", 1.0, 20.0, 0.5, s.app.point_size * 1000)
        self.size.on_update(lambda ev: setattr(self.cloud, "point_size", self.size.value / 1000))
        self.cameras = gui.add_checkbox("Cameras", True)
        self.cameras.on_update(lambda ev: self._toggle_frustums(s, self.cameras.value))
        self._build_scene(s)

    @staticmethod
    def _layer_names(s: "Session") -> list[str]:
        return [layer.name for layer in available_layers(s.layer_input(), s.state)]

    def _build_scene(self, s: "Session") -> None:
        d = s.app.data
        sc = s.client.scene
        self._add_cloud(s)
        self.frustum_scale = frustum_scale(d)  # the default camera keeps these out of its way
        import viser.transforms as vtf

        self.frustums = []
        for vi, v in enumerate(d.views):
            cam = v.camera
            step = downscale_step(cam.width, _THUMB_MAX_WIDTH)
            fr = sc.add_camera_frustum(
                f"/cameras/view{vi}", fov=float(2 * np.arctan2(cam.height / 2, cam.fy)), aspect=cam.width / cam.height,
                scale=self.frustum_scale, thickness=2.0, thickness_units="screen",
                image=np.ascontiguousarray(v.rgb[::step, ::step]), jpeg_quality=70,
                wxyz=vtf.SO3.from_matrix(cam.T_world_camera[:3, :3]).wxyz, position=cam.T_world_camera[:3, 3],
                color=_SELECTED_VIEW if vi == s.state.view else _OTHER_VIEW,
            )
            fr.on_click(lambda ev, vi=vi: s.select_view(vi))
            self.frustums.append(fr)
        # per-view nodes, built once: the 3D centroids of that view's masks; toggled on view change
        self.centroids = []
        for vi in range(len(d.trace.frames)):
            nodes = d.view_nodes(vi)
            ok = nodes[np.isfinite(d.node_centroid[nodes, 0])]
            pts = d.node_centroid[ok].astype(np.float32) if len(ok) else np.zeros((1, 3), np.float32)
            cols = label_colors(d.node_instance[ok]) if len(ok) else np.zeros((1, 3), np.uint8)
            self.centroids.append(sc.add_point_cloud(
                f"/views/view{vi}/mask_centroids", pts, cols, point_size=self.frustum_scale * 0.25,
                point_shape="circle", precision="float32", visible=vi == s.state.view))

    def _add_cloud(self, s: "Session") -> None:
        d = s.app.data
        centre = d.centre
        pts = (d.seg.points[s.lod_idx] - centre).astype(np.float32)
        self.moved = False
        self.cloud = s.client.scene.add_point_cloud(
            "/cloud", pts, s.point_colors(), point_size=s.app.point_size, point_shape="rounded", position=centre,
            precision="float16")

    def recolor(self, s: "Session") -> None:
        """Colour-only update (viser sends colours, not points), plus positions when an event source moves them."""
        src = s.replay_source() if s.state.color_mode == "replay" else None
        pts = src.points(s.state.event, s.lod_idx) if src is not None else None
        if s.state.color_mode == "update":  # the Updates tab's scene after (or before) its update
            from clutt3r_viewer.panels.updates import update_positions

            pts = update_positions(s)
        if pts is not None:
            self.cloud.points = (pts - s.app.data.centre).astype(np.float32)
            self.moved = True
        elif self.moved:
            self.cloud.points = (s.app.data.seg.points[s.lod_idx] - s.app.data.centre).astype(np.float32)
            self.moved = False
        self.cloud.colors = s.point_colors()
        s.colour_updates += 1

    def set_lod(self, s: "Session", lod: str) -> None:
        with s.lock:
            if lod == s.state.lod:
                return
            s.state.lod = lod
            s.lod_idx = lod_indices(len(s.app.data.seg.points), LOD_OPTIONS[lod])
            self._add_cloud(s)  # same name: replaces the node (new points, the run's positions)
            s.changed(Change.LOD)  # other panels; and an event source that moves points moves these

    def _toggle_frustums(self, s: "Session", on: bool) -> None:
        with s.client.atomic():
            for f in self.frustums:
                f.visible = on

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.VIEW:
            for k, n in enumerate(self.centroids):
                n.visible = k == s.state.view
            for k, f in enumerate(self.frustums):
                f.color = _SELECTED_VIEW if k == s.state.view else _OTHER_VIEW
        if change & Change.COLOUR:
            names = self._layer_names(s)
            if tuple(names) != tuple(self.color.options):
                self.color.options = names
            if self.color.value != s.state.color_mode and s.state.color_mode in names:
                self.color.value = s.state.color_mode
        if change & (Change.VIEW | Change.NODE | Change.LABELS | Change.COLOUR):
            self.recolor(s)
        elif change & Change.LOD and s.state.color_mode in ("replay", "update"):
            self.recolor(s)


class InstancesPanel(Panel):
    """The instance table (corrected instances when the run has edits)."""

    tab = "Scene"
    table: "viser.GuiMarkdownHandle"

    def build(self, s: "Session") -> None:
        self.table = s.client.gui.add_markdown(self.markdown(s))

    def refresh(self, s: "Session", change: Change) -> None:
        if change & Change.LABELS:
            self.table.content = self.markdown(s)

    @staticmethod
    def markdown(s: "Session") -> str:
        seg = s.app.data.seg
        ann = s.app.annotations
        if ann is not None and ann.num_ops:  # corrected: masks are those of the original instance
            lab = ann.current
            lines = ["| inst | conf | category | points |", "|---|---|---|---|"]
            npts = lab.point_counts()
            for k in lab.alive:
                lines.append(f"| I{k} | {lab.scores[k]:.2f} | {lab.categories[k]} | {int(npts[k])} |")
            return "\n".join(lines)
        lines = ["| inst | conf | masks | points |", "|---|---|---|---|"]
        npts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
        for k in range(seg.num_instances):
            lines.append(f"| I{k} | {seg.scores[k]:.2f} | {len(seg.instance_nodes(k))} | {int(npts[k])} |")
        return "\n".join(lines)
