"""The parallel-jaw gripper: the one source of its numbers (docs/conventions.md, "Gripper").

``T_world_gripper`` (4x4, metres, world z up) has its origin at the grasp centre, the
midpoint between the two finger pads; +z is the approach direction (palm towards
fingertips); +x is the closing axis; y = z x x. ``width`` is the opening between the inner
finger faces, 0 < width <= 0.08 m (Franka Hand). In the gripper frame:

- closing region between the pads: |x| < width/2, |y| <= 0.01, -0.02 <= z <= 0.02;
- fingers: boxes width/2 <= |x| <= width/2 + 0.01, |y| <= 0.01, -0.045 <= z <= 0.02;
- palm: |x| <= 0.105, |y| <= 0.03, -0.11 <= z <= -0.045.

The planner (collision checks), the evaluator and ``static/make_gripper.py`` (the viewer's
mesh) all read these boxes from ``GripperGeometry``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["GripperGeometry", "Box", "FRANKA", "box_grid"]


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in the gripper frame: ``centre`` (3,) and ``half`` (3,) extents, metres."""

    centre: tuple[float, float, float]
    half: tuple[float, float, float]

    @property
    def lo(self) -> np.ndarray:
        return np.asarray(self.centre) - np.asarray(self.half)

    @property
    def hi(self) -> np.ndarray:
        return np.asarray(self.centre) + np.asarray(self.half)

    def contains(self, p: np.ndarray, pad: float = 0.0) -> np.ndarray:
        """(..., 3) points in the gripper frame -> (...,) bool, inside the box grown by ``pad`` metres."""
        d = np.abs(np.asarray(p) - np.asarray(self.centre))
        return np.all(d <= np.asarray(self.half) + pad, axis=-1)


@dataclass(frozen=True)
class GripperGeometry:
    """Parallel-jaw gripper boxes in the gripper frame (issue 9's fixed convention; metres).

    Defaults are the Franka Hand of the convention; every field is a plain number so a
    different hand is one constructor call.
    """

    max_width: float = 0.08
    """Largest opening between the inner finger faces (Franka Hand: 80 mm)."""
    finger_thickness: float = 0.01
    """Finger extent along x, outside the opening: width/2 <= |x| <= width/2 + this."""
    finger_half_y: float = 0.01
    """Finger (and pad) half extent along y."""
    finger_z: tuple[float, float] = (-0.045, 0.02)
    """Finger extent along z (approach); the fingertips are at the upper bound."""
    closing_z: tuple[float, float] = (-0.02, 0.02)
    """Closing region (the pads) along z."""
    palm_half_x: float = 0.105
    """Palm half extent along the closing axis (does not change with the width)."""
    palm_half_y: float = 0.03
    """Palm half extent along y."""
    palm_z: tuple[float, float] = (-0.11, -0.045)
    """Palm extent along z; the fingers start at its front face."""

    def __post_init__(self) -> None:
        if not 0 < self.max_width:
            raise SceneError(f"GripperGeometry.max_width must be > 0, got {self.max_width}")
        for name in ("finger_z", "closing_z", "palm_z"):
            lo, hi = getattr(self, name)
            if not lo < hi:
                raise SceneError(f"GripperGeometry.{name} must be (low, high) with low < high, got {(lo, hi)}")
        if self.palm_half_x < self.max_width / 2 + self.finger_thickness:
            raise SceneError("GripperGeometry: the palm must span the fully opened fingers")

    def check_width(self, width: float) -> float:
        w = float(width)
        if not 0 < w <= self.max_width + 1e-9:
            raise SceneError(f"gripper width must be in (0, {self.max_width}] m, got {w}")
        return w

    def boxes(self, width: float) -> dict[str, Box]:
        """Named boxes at opening ``width`` (metres): finger_left (x < 0), finger_right, palm, closing."""
        w = self.check_width(width) / 2
        ft = self.finger_thickness
        fz0, fz1 = self.finger_z
        cz0, cz1 = self.closing_z
        pz0, pz1 = self.palm_z
        fc, fh = (fz0 + fz1) / 2, (fz1 - fz0) / 2
        return {
            "finger_left": Box((-(w + ft / 2), 0.0, fc), (ft / 2, self.finger_half_y, fh)),
            "finger_right": Box((w + ft / 2, 0.0, fc), (ft / 2, self.finger_half_y, fh)),
            "palm": Box((0.0, 0.0, (pz0 + pz1) / 2), (self.palm_half_x, self.palm_half_y, (pz1 - pz0) / 2)),
            "closing": Box((0.0, 0.0, (cz0 + cz1) / 2), (w, self.finger_half_y, (cz1 - cz0) / 2)),
        }

    @property
    def reach(self) -> float:
        """Largest distance from the grasp centre to any point of the fully opened gripper, metres."""
        x = self.palm_half_x
        y = max(self.palm_half_y, self.finger_half_y)
        z = max(abs(self.palm_z[0]), abs(self.finger_z[1]))
        return float(np.sqrt(x * x + y * y + z * z))


FRANKA = GripperGeometry()
"""The default gripper of the convention."""


def box_grid(box: Box, spacing: float) -> tuple[np.ndarray, float]:
    """Sample points filling ``box`` on a regular grid of at most ``spacing`` metres.

    Returns (points (S, 3) float64 in the box's frame, cover radius in metres): every point
    of the box is within the cover radius of a sample (the half diagonal of a grid cell),
    so "no obstacle within the cover radius of any sample" proves the box free.
    """
    half = np.asarray(box.half, float)
    n = np.maximum(1, np.ceil(2 * half / spacing - 1e-9)).astype(int)
    cell = 2 * half / n
    axes = [(-half[i] + cell[i] * (np.arange(n[i]) + 0.5)) + box.centre[i] for i in range(3)]
    g = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    return g, float(np.linalg.norm(cell) / 2)
