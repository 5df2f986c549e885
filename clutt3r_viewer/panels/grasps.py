"""The Grasps tab: grasp candidates as gripper outlines; the selected one as the gripper mesh."""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_viewer.assets import gripper_mesh
from clutt3r_viewer.data import ramp_colors
from clutt3r_viewer.layers import HIGHLIGHT
from clutt3r_viewer.panels.base import Panel

if TYPE_CHECKING:
    import viser

    from clutt3r_viewer.app import Session, ViewerApp

__all__ = ["GraspsPanel", "gripper_segments"]


def gripper_segments(T: np.ndarray, width: float, depth: float = 0.05) -> np.ndarray:
    """(4, 2, 3) float32 line segments of a parallel-jaw gripper at ``T_world_gripper``.

    Gripper frame: z = approach direction, x = closing direction; the fingertips are at the origin.
    """
    w = float(width) / 2
    local = np.array([
        [[-w, 0, 0], [w, 0, 0]],              # palm bar
        [[-w, 0, 0], [-w, 0, depth]],         # left finger
        [[w, 0, 0], [w, 0, depth]],           # right finger
        [[0, 0, 0], [0, 0, -depth]],          # wrist
    ], np.float64)
    local[..., 2] -= depth  # fingertips at the origin, palm behind them
    p = local.reshape(-1, 3) @ T[:3, :3].T + T[:3, 3]
    return p.reshape(4, 2, 3).astype(np.float32)


class GraspsPanel(Panel):
    tab = "Grasps"
    summary: "viser.GuiMarkdownHandle"
    grasp: "viser.GuiDropdownHandle[str]"
    all: "viser.LineSegmentsHandle | None" = None
    selected: "viser.MeshHandle | viser.LineSegmentsHandle | None" = None

    @classmethod
    def available(cls, app: "ViewerApp") -> bool:
        return app.data.grasps is not None

    def build(self, s: "Session") -> None:
        g = s.app.data.grasps
        gui = s.client.gui
        order = np.argsort(-g.scores)
        self.summary = gui.add_markdown(f"{len(g.scores)} grasp candidates")
        self.grasp = gui.add_dropdown(
            "Grasp", ["none"] + [f"{int(k)}: I{int(g.instance[k])} score {g.scores[k]:.2f}" for k in order[:50]],
            initial_value="none")
        self.grasp.on_update(lambda ev: self.select_grasp(s, self.grasp.value))
        if len(g.scores):
            segs = np.concatenate([gripper_segments(g.poses[k], g.widths[k]) for k in range(len(g.scores))])
            col = np.repeat(ramp_colors(g.scores, float(g.scores.min()), float(g.scores.max())), 4, axis=0)
            self.all = s.client.scene.add_line_segments("/grasps/all", segs, np.repeat(col[:, None], 2, axis=1),
                                                        thickness=1.5, thickness_units="screen")

    def select_grasp(self, s: "Session", value: str) -> None:
        with s.lock:
            g = s.app.data.grasps
            if value == "none":
                s.state.grasp = -1
                if self.selected is not None:
                    self.selected.visible = False
                return
            k = int(value.split(":")[0])
            s.state.grasp = k
            mesh = gripper_mesh(g.poses[k], g.widths[k])
            if mesh is not None:  # the gripper mesh of static/, fingers at this grasp's width
                self.selected = s.client.scene.add_mesh_simple(
                    "/grasps/selected", mesh[0], mesh[1], color=tuple(int(c) for c in HIGHLIGHT))
            else:
                self.selected = s.client.scene.add_line_segments(
                    "/grasps/selected", gripper_segments(g.poses[k], g.widths[k]), HIGHLIGHT, thickness=5.0,
                    thickness_units="screen")
