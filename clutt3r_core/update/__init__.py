"""Scene update from one post-interaction image (Sec. III-C): registry kind ``pose_optimizer``.

``UpdateFrame`` is what the viewer replays for one post-interaction frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from clutt3r_core.scene import Camera

__all__ = ["UpdateFrame", "PoseOptimizer"]


@dataclass(frozen=True, eq=False)
class UpdateFrame:
    """One post-interaction frame to replay.

    Attributes:
        frame: frame index.
        rgb: (H, W, 3) uint8 image, or None.
        camera: its camera, or None.
        point_instance: (N,) int32 instance per point of the run's cloud after the update
            (-1 = removed / none), or None when only the image is known.
        text: a markdown summary of what changed.
    """

    frame: int
    rgb: np.ndarray | None = None
    camera: Camera | None = None
    point_instance: np.ndarray | None = None
    text: str = ""


@runtime_checkable
class PoseOptimizer(Protocol):
    """Estimates the rigid motion of a displaced instance from one new image (Sec. III-C)."""

    name: str

    def optimize(self, problem: "object") -> "object":
        """problem: the instance's points, colours, the new view and its mask -> the pose result
        (types defined with the update stage)."""
        ...
