"""The Grasps tab: plan grasps for a picked instance, draw the top N, inspect and export one.

Target: the instance dropdown, the tree node selected in the Tree tab (its instance), or the
best instance of the last text query ("Use query target"). Before any update the ids are the Edit
tab's, as they are now (``scene_step.step_zero_of``: a merged instance is planned on the union of
its parts' points before the contact rule, a deleted or merged id is no target and the tab says
why), as ``clutt3r grasp`` reads the correction log. "Plan grasps" runs the default
``grasp_planner`` (``clutt3r_core.grasping``) on the run's fused cloud with the run's depth
views (unseen-space check). The top N grippers are drawn as outlines at their widths,
coloured by score; the selected one is drawn with the gripper mesh, its closing region
(the box between the pads) and its two contacts. "Export" writes ``RUN/grasps.json`` and
``RUN/grasps.npz`` as ``clutt3r grasp`` does. A run that already has ``grasps.npz`` opens
with those grasps. Gripper frame: docs/conventions.md ("Gripper").
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_core.grasping.gripper import FRANKA
from clutt3r_viewer.assets import gripper_mesh
from clutt3r_viewer.data import ramp_colors
from clutt3r_viewer.edit import option_id
from clutt3r_viewer.layers import HIGHLIGHT
from clutt3r_viewer.panels.base import Change, Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["GraspsPanel", "gripper_segments", "closing_region_segments"]


def _transform(local: np.ndarray, T: np.ndarray) -> np.ndarray:
    p = local.reshape(-1, 3) @ np.asarray(T)[:3, :3].T + np.asarray(T)[:3, 3]
    return p.reshape(local.shape).astype(np.float32)


def gripper_segments(T: np.ndarray, width: float) -> np.ndarray:
    """(4, 2, 3) float32 line segments of the gripper at ``T_world_gripper`` (docs/conventions.md).

    Origin at the grasp centre; z = approach, x = closing: palm bar, the two fingers (inner faces
    at x = -/+ width / 2, palm face to fingertips) and the wrist along -z.
    """
    w = float(width) / 2
    z0, z1 = FRANKA.finger_z
    zp = FRANKA.palm_z[0]
    local = np.array([
        [[-w, 0, z0], [w, 0, z0]],      # palm bar at the palm's front face
        [[-w, 0, z0], [-w, 0, z1]],     # left finger, to its tip
        [[w, 0, z0], [w, 0, z1]],       # right finger
        [[0, 0, z0], [0, 0, zp]],       # wrist, back to the palm's rear face
    ], np.float64)
    return _transform(local, T)


def closing_region_segments(T: np.ndarray, width: float) -> np.ndarray:
    """(12, 2, 3) float32 edges of the closing region box (between the pads) at ``T_world_gripper``."""
    b = FRANKA.boxes(float(min(max(width, 1e-4), FRANKA.max_width)))["closing"]
    lo, hi = b.lo, b.hi
    c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    edges = [(i, j) for i in range(8) for j in range(i + 1, 8) if bin(i ^ j).count("1") == 1]
    return _transform(np.stack([c[[i, j]] for i, j in edges]), T)


class GraspsPanel(Panel):
    tab = "Grasps"
    target: "viser.GuiDropdownHandle[str]"
    use_query: "viser.GuiButtonHandle"
    top: "viser.GuiSliderHandle[int]"
    plan: "viser.GuiButtonHandle"
    summary: "viser.GuiMarkdownHandle"
    grasp: "viser.GuiDropdownHandle[str]"
    export: "viser.GuiButtonHandle"
    all: "viser.LineSegmentsHandle | None" = None
    selected: "viser.MeshHandle | viser.LineSegmentsHandle | None" = None
    region: "viser.LineSegmentsHandle | None" = None
    contacts: "viser.PointCloudHandle | None" = None

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return app.data.grasps is not None or app.data.seg.num_instances > 0

    def build(self, s: "Session") -> None:
        gui = s.client.gui
        self.target = gui.add_dropdown("Target", self._options(s), hint="instance to grasp in the scene shown (after "
                                       "the updates chosen in the Updates tab); selecting a tree node or an instance "
                                       "picks it")
        self.use_query = gui.add_button("Use query target", hint="the best instance of the Query tab's last query")
        self.use_query.on_click(lambda ev: self._use_query(s))
        self.top = gui.add_slider("Top N", min=1, max=50, step=1, initial_value=10)
        self.plan = gui.add_button("Plan grasps")
        self.plan.on_click(lambda ev: self.plan_for(s, option_id(self.target.value)))
        self.summary = gui.add_markdown("_pick a target and plan_")
        self.grasp = gui.add_dropdown("Grasp", ["none"], initial_value="none")
        self.grasp.on_update(lambda ev: self.select_grasp(s, self.grasp.value))
        self.export = gui.add_button("Export grasps.json / grasps.npz")
        self.export.on_click(lambda ev: self._export(s))
        self._grasps = s.app.data.grasps
        self._target = -1 if self._grasps is None or not len(self._grasps) else int(self._grasps.instance[0])
        self._step: int | None = None  # updates applied to the scene planned in (None: unknown / no updates)
        self._corrections: dict | None = None  # the correction log state a step-0 plan's ids came from
        if self._grasps is not None:
            self.summary.content = f"{len(self._grasps)} grasps from the run's grasps.npz"
            self._draw(s)

    def refresh(self, s: "Session", change: Change) -> None:
        if change & (Change.SCENE | Change.LABELS):  # an edit changes the ids at step 0
            opts = self._options(s)
            if tuple(opts) != tuple(self.target.options):
                keep = option_id(self.target.value)
                self.target.options = opts
                self._set_target(keep)
        if change & Change.NODE and s.state.node >= 0:
            k = int(s.app.data.node_instance[s.state.node])
            if k >= 0:
                self._set_target(k)
        if change & Change.INSTANCE and s.state.instance >= 0:
            self._set_target(s.state.instance)

    @staticmethod
    def _options(s: "Session") -> list[str]:
        """The instances of the scene shown, with their point counts there (added ones included)."""
        seg = s.app.data.seg
        if s.scene_step() == 0:
            from clutt3r_viewer.scene_step import step_zero_of

            z = step_zero_of(s.app.data, getattr(s.app, "annotations", None))
            if z.corrected:  # the Edit tab's ids now (deleted and merged ones are no target)
                inst = z.labels.instance
                counts = np.bincount(inst[inst >= 0], minlength=z.labels.num_ids)
                return [f"I{k} ({int(counts[k])} pts)" for k in z.labels.ids.tolist()] or ["none"]
            counts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
            return [f"I{k} ({int(counts[k])} pts)" for k in range(seg.num_instances) if k not in z.gone] or ["none"]
        from clutt3r_viewer.scene_step import shown_scene

        sc = shown_scene(s.app.data, s.scene_step(), np.arange(len(seg.points)))
        n = max(int(sc.present.max(initial=-1)) + 1, seg.num_instances)
        counts = (np.bincount(sc.instance[sc.instance >= 0], minlength=n)
                  + np.bincount(sc.added_instance, minlength=n))
        return [f"I{k} ({int(counts[k])} pts{', new' if k in sc.added_in else ''})" for k in sc.present.tolist()] \
            or ["none"]

    def _set_target(self, k: int) -> None:
        for opt in self.target.options:
            if option_id(opt) == k:
                self.target.value = opt

    def _use_query(self, s: "Session") -> None:
        if s.state.query_best < 0:
            s.notify("Grasps", "run a query in the Query tab first")
            return
        self._set_target(int(s.state.query_best))

    def plan_for(self, s: "Session", k: int) -> None:
        """Plan grasps on instance ``k`` with the default planner and draw the top N."""
        from clutt3r_core.grasping import DepthView
        from clutt3r_core.grasping.request import request_from_segmentation
        from clutt3r_core.registry import create_backend

        with s.lock:
            d = s.app.data
            step = s.scene_step()
            if step > 0:  # the scene after the updates shown: moved, removed and added instances
                from clutt3r_viewer.scene_step import scene_grasp_request

                if k not in set(s.scene().present.tolist()):
                    s.notify("Grasps", f"I{k} is not in the scene after update {step}: pick a target instance")
                    return
                req = scene_grasp_request(d, step, k)
                views = ()
            else:  # the Edit tab's ids as they are now, as `clutt3r grasp` reads the correction log
                from clutt3r_core.errors import SceneError
                from clutt3r_viewer.scene_step import step_zero_of

                z = step_zero_of(d, getattr(s.app, "annotations", None))
                try:
                    z.check_target(k)
                except SceneError as e:
                    s.notify("Grasps", f"{e}; pick a target instance")
                    return
                views = tuple(DepthView(v.camera, v.depth) for v in d.views if v.depth is not None)
                req = request_from_segmentation(d.seg, k, views, labels=z)
            gs = create_backend("grasp_planner").plan(req)
            self._grasps, self._target = gs.top(int(self.top.value)), k
            self._step = step if d.updates else None  # recorded as clutt3r grasp records it
            self._corrections = z.to_json() if step == 0 else self._chain_corrections(s)
            self._target_points = int(req.target.sum())
            note = gs.message or ("" if views else
                                  f"after update {step}: cloud-only collision checks (the initial views no longer "
                                  "show this scene)" if step > 0 else "no depth views: cloud-only collision checks")
            self.summary.content = (f"**{len(self._grasps)}** grasps for I{k}" if len(self._grasps) else
                                    f"no grasp for I{k}") + f" ({self._target_points} target points)" \
                + (f"  \n_{note}_" if note else "")
            self._draw(s)

    @staticmethod
    def _chain_corrections(s: "Session") -> dict | None:
        """The log state the update chain's ids came from (its state.json "labels"), as ``clutt3r grasp
        --step`` records it (``SceneAfter.corrections``); None without a run folder or a log."""
        from clutt3r_core.update.run_labels import chain_source

        run_dir = getattr(getattr(s.app, "annotations", None), "run_dir", None)
        rec = chain_source(run_dir) if run_dir is not None else None
        return None if rec is None or rec[1] is None else rec[1].record()

    def _draw(self, s: "Session") -> None:
        g = self._grasps
        for h in (self.all, self.selected, self.region, self.contacts):
            if h is not None:
                h.visible = False
        self.grasp.options = ["none"] + [f"{k}: I{int(g.instance[k])} score {g.scores[k]:.2f} "
                                         f"w {g.widths[k] * 1000:.0f} mm" for k in range(len(g))]
        self.grasp.value = "none"
        if len(g):
            segs = np.concatenate([gripper_segments(g.poses[k], g.widths[k]) for k in range(len(g))])
            col = np.repeat(ramp_colors(g.scores, float(g.scores.min()), float(g.scores.max())), 4, axis=0)
            self.all = s.client.scene.add_line_segments("/grasps/all", segs, np.repeat(col[:, None], 2, axis=1),
                                                        thickness=2.0, thickness_units="screen")

    def select_grasp(self, s: "Session", value: str) -> None:
        with s.lock:
            g = self._grasps
            for h in (self.selected, self.region, self.contacts):
                if h is not None:
                    h.visible = False
            if value == "none" or g is None:
                s.state.grasp = -1
                return
            k = int(value.split(":")[0])
            s.state.grasp = k
            T, w = g.poses[k], float(g.widths[k])
            mesh = gripper_mesh(T, w)
            if mesh is not None:  # the gripper mesh of static/, fingers at this grasp's width
                self.selected = s.client.scene.add_mesh_simple(
                    "/grasps/selected", mesh[0], mesh[1], color=tuple(int(c) for c in HIGHLIGHT), opacity=0.6)
            else:
                self.selected = s.client.scene.add_line_segments(
                    "/grasps/selected", gripper_segments(T, w), HIGHLIGHT, thickness=5.0, thickness_units="screen")
            self.region = s.client.scene.add_line_segments(
                "/grasps/closing_region", closing_region_segments(T, w), (40, 200, 255), thickness=3.0,
                thickness_units="screen")
            if g.contacts is not None:
                self.contacts = s.client.scene.add_point_cloud(
                    "/grasps/contacts", np.asarray(g.contacts[k], np.float32),
                    np.array([[255, 40, 40], [255, 40, 40]], np.uint8), point_size=0.008, point_shape="circle")

    def _export(self, s: "Session") -> None:
        ann = s.app.annotations
        run_dir = getattr(ann, "run_dir", None)
        if run_dir is None or self._grasps is None:
            s.notify("Grasps", "nothing to export (plan first) or no run folder (read-only view)")
            return
        self._grasps.save_json(run_dir / "grasps.json", self._target, step=self._step, corrections=self._corrections)
        self._grasps.save_npz(run_dir / "grasps.npz")
        s.notify("Grasps", f"wrote {run_dir / 'grasps.json'} and grasps.npz")
