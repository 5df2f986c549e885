"""The 3D scene (point cloud, camera frustums, mask centroids) and the Scene tab's display controls."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.camera import frustum_scale
from clutt3r_viewer.data import label_colors, lod_indices
from clutt3r_viewer.edit import option_id
from clutt3r_viewer.layers import available_layers
from clutt3r_viewer.panels.base import Change, Panel, downscale_step
from clutt3r_viewer.scene_step import shown_scene

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session

__all__ = ["ScenePanel", "InstancesPanel", "LOD_OPTIONS", "instance_option"]

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
    moved: bool = False  # the cloud shows an event source's or an update's positions, not the run's
    added: "viser.PointCloudHandle | None" = None
    """The instances the updates of the scene shown added (not in the run's cloud), or None."""
    _added_key: tuple | None = None

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.color = gui.add_dropdown("Colour", self._layer_names(s), initial_value=s.state.color_mode)
        self.color.on_update(lambda ev: s.set_color_mode(self.color.value))
        self.lod = gui.add_dropdown("Max points", tuple(LOD_OPTIONS), initial_value=s.state.lod,
                                    hint="level of detail: points sent to this tab")
        self.lod.on_update(lambda ev: self.set_lod(s, self.lod.value))
        self.size = gui.add_slider("Point size (mm)", 1.0, 20.0, 0.5, s.app.point_size * 1000)
        self.size.on_update(lambda ev: self._set_point_size(self.size.value / 1000))
        self.cameras = gui.add_checkbox("Cameras", True)
        self.cameras.on_update(lambda ev: self._toggle_frustums(s, self.cameras.value))
        self._build_scene(s)

    def _set_point_size(self, size: float) -> None:
        for h in (self.cloud, self.added):
            if h is not None:
                h.point_size = size

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
        """Colour-only update (viser sends colours, not points), plus positions when the scene
        shown moved points (an update) or an event source moves them (the Replay tab), and the
        second cloud of the instances updates added."""
        st = s.state
        src = s.replay_source() if st.color_mode == "replay" else None
        added = None
        if src is not None:  # the replay's own scene: the grouping's initial one, or a pose replay's
            pts = src.points(st.event, s.lod_idx)
            fn = getattr(src, "added", None)
            added = fn(st.event) if fn is not None else None
        else:
            pts = None
            # the run itself (no update shown) is the cloud as built: no ShownScene to build and
            # cache (57 ms and 28 MiB per level of detail at 1M points, 1.6 ms per recolour)
            if s.scene_step() > 0:
                sc = s.scene()
                pts = sc.points
                if len(sc.added_points):
                    added = (sc.added_points, sc.added_instance, s.added_colors())
        if pts is not None:
            self.cloud.points = (pts - s.app.data.centre).astype(np.float32)
            self.moved = True
        elif self.moved:
            self.cloud.points = (s.app.data.seg.points[s.lod_idx] - s.app.data.centre).astype(np.float32)
            self.moved = False
        self.cloud.colors = s.point_colors()
        self._draw_added(s, added)
        s.colour_updates += 1

    def _draw_added(self, s: "Session", added) -> None:
        """The instances the shown updates added ((points, instance, colours) or None): not in the
        run's cloud, so a second cloud, replaced when they change, recoloured otherwise."""
        if added is None or not len(added[0]):
            if self.added is not None:
                self.added.remove()
                self.added = None
                self._added_key = None
            return
        pts, inst, col = added
        key = (len(pts), float(np.asarray(pts).sum()))
        if self.added is not None and key == self._added_key:
            self.added.colors = col
            return
        if self.added is not None:
            self.added.remove()
        centre = s.app.data.centre
        self.added = s.client.scene.add_point_cloud(
            "/cloud_added", (np.asarray(pts) - centre).astype(np.float32), col, point_size=self.cloud.point_size,
            point_shape="rounded", position=centre, precision="float16")
        self._added_key = key

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
        if change & (Change.VIEW | Change.NODE | Change.LABELS | Change.COLOUR | Change.SCENE | Change.INSTANCE):
            self.recolor(s)
        elif change & Change.LOD and (s.state.color_mode == "replay" or s.scene_step() > 0):
            self.recolor(s)


class InstancesPanel(Panel):
    """The instance table of the scene shown (corrected instances when the run has edits; after
    an update: the instances then, added ones marked new, removed ones listed apart) and the
    instance selection (highlighted in every colour mode; the Grasps tab's target)."""

    tab = "Scene"
    select: "viser.GuiDropdownHandle[str]"
    table: "viser.GuiMarkdownHandle"

    def build(self, s: "Session") -> None:
        self.select = s.client.gui.add_dropdown("Instance", self.options(s), initial_value=NO_INSTANCE,
                                                hint="highlight an instance of the scene shown (in every colour mode)")
        self.select.on_update(lambda ev: s.select_instance(option_id(self.select.value)))
        self.table = s.client.gui.add_markdown(self.markdown(s))

    def refresh(self, s: "Session", change: Change) -> None:
        if change & (Change.LABELS | Change.SCENE):
            self.table.content = self.markdown(s)
            opts = self.options(s)
            if tuple(opts) != tuple(self.select.options):
                self.select.options = opts
        if change & (Change.INSTANCE | Change.SCENE | Change.LABELS):
            want = instance_option(s.state.instance)
            if self.select.value != want and want in self.select.options:
                self.select.value = want

    @staticmethod
    def options(s: "Session") -> list[str]:
        if s.scene_step() == 0:
            ann = s.app.annotations
            ids = list(ann.current.alive) if ann is not None and ann.num_ops else range(s.app.data.seg.num_instances)
        else:
            ids = s.scene().present.tolist()
        return [NO_INSTANCE] + [instance_option(int(k)) for k in ids]

    @staticmethod
    def markdown(s: "Session") -> str:
        seg = s.app.data.seg
        if s.scene_step() > 0:
            return _scene_markdown(s)
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


NO_INSTANCE = "none"


def instance_option(k: int) -> str:
    """Dropdown text of instance ``k`` ("I3"; read back by ``edit.option_id``, as the Edit tab's)."""
    return NO_INSTANCE if k < 0 else f"I{k}"


def _scene_markdown(s: "Session") -> str:
    """The instances after the updates shown: the run's (conf, points) and the added ones
    ("new in frame F", no grouping confidence), then the removed ones."""
    from clutt3r_viewer.scene_step import chain_steps

    d = s.app.data
    seg = d.seg
    step = s.scene_step()
    sc = shown_scene(d, step, np.arange(len(seg.points)))  # all points: counts independent of the LOD
    steps = chain_steps(d)[:step]
    moved = {k: st.frame for st in steps for k, _, _ in st.displaced}
    gone = {k: st.frame for st in steps for k in st.removed}
    npts = np.bincount(sc.instance[sc.instance >= 0], minlength=seg.num_instances)
    nadd = dict(zip(*np.unique(sc.added_instance, return_counts=True)))
    lines = [f"_after update {step} of {len(d.updates)}_", "", "| inst | conf | status | points |", "|---|---|---|---|"]
    for k in sc.present.tolist():
        if k in sc.added_in:
            status = f"**new** (frame {sc.added_in[k]})" + (f", moved (frame {moved[k]})" if k in moved else "")
            lines.append(f"| I{k} | - | {status} | {int(nadd.get(k, 0))} |")
        else:
            status = f"moved (frame {moved[k]})" if k in moved else "in place"
            lines.append(f"| I{k} | {seg.scores[k]:.2f} | {status} | {int(npts[k])} |")
    if gone:
        lines += ["", "removed: " + ", ".join(f"I{k} (frame {f})" for k, f in sorted(gone.items()))]
    return "\n".join(lines)
