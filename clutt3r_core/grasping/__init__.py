"""Grasp poses for a chosen instance: registry kind ``grasp_planner``.

Gripper convention (docs/conventions.md): ``T_world_gripper`` (4x4, metres, world z up)
has its origin at the grasp centre, the midpoint between the two finger pads; +z is the
approach direction (palm towards fingertips); +x is the closing axis; y = z x x.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError

__all__ = ["GraspSet", "GraspPlanner"]


@dataclass(frozen=True, eq=False)
class GraspSet:
    """Ranked parallel-jaw grasps.

    Attributes:
        poses: (G, 4, 4) float64 ``T_world_gripper``; gripper z = approach, x = closing direction.
        widths: (G,) float32 opening in metres.
        scores: (G,) float32 quality, higher is better.
        instance: (G,) int32 target instance, -1 = unknown.
    """

    poses: np.ndarray
    widths: np.ndarray
    scores: np.ndarray
    instance: np.ndarray

    def __post_init__(self) -> None:
        g = len(self.scores)
        if np.shape(self.poses) != (g, 4, 4) or np.shape(self.widths) != (g,) or np.shape(self.instance) != (g,):
            raise SceneError("GraspSet: poses (G,4,4), widths (G,), scores (G,), instance (G,) must agree")

    def __len__(self) -> int:
        return len(self.scores)

    @staticmethod
    def load(path: str | Path) -> "GraspSet":
        try:
            z = np.load(path)
            return GraspSet(
                poses=z["poses"].astype(np.float64), widths=z["widths"].astype(np.float32),
                scores=z["scores"].astype(np.float32), instance=z["instance"].astype(np.int32),
            )
        except (OSError, ValueError, KeyError) as e:
            raise SceneFileError(path, f"not a grasp set ({e})") from None


@runtime_checkable
class GraspPlanner(Protocol):
    """Plans grasps on one instance of a segmented scene."""

    name: str

    def plan(self, request: "object") -> GraspSet:
        """request: the target's points and the scene's geometry (type defined with the planner)."""
        ...
