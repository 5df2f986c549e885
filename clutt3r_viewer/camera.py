"""The default camera: the objects (support excluded) filling the view, from the first camera's side."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_viewer.data import ViewerData

__all__ = ["CameraPose", "object_points", "bounding_sphere", "default_camera"]

FOV = np.deg2rad(45.0)
"""Vertical field of view of the default camera, radians (ours: narrower than three.js' 75 degrees,
so the pile is seen with little perspective distortion)."""
MARGIN = 1.1
"""Distance factor over the one at which the bounding sphere exactly fills the view height (ours)."""
ELEVATION = (np.deg2rad(25.0), np.deg2rad(60.0))
"""Elevation range of the view direction, radians: the first camera's elevation clamped to it
(ours: below 25 degrees the objects hide each other, above 60 the pile reads as a flat map)."""


@dataclass(frozen=True)
class CameraPose:
    """A viewer camera in world metres: ``position`` looks at ``look_at``; ``fov`` vertical, radians."""

    look_at: np.ndarray
    position: np.ndarray
    fov: float

    def __post_init__(self) -> None:
        if np.shape(self.look_at) != (3,) or np.shape(self.position) != (3,):
            raise ValueError("look_at and position must be (3,)")


def object_points(data: ViewerData) -> np.ndarray:
    """(M, 3) float64 points of the objects: instance points, else points off the support super-voxels,
    else every point (a run with nothing but support)."""
    seg = data.seg
    obj = seg.instance >= 0
    if not obj.any() and len(seg.sv_support):
        obj = ~seg.sv_support[seg.sv_labels]
    return (seg.points[obj] if obj.any() else seg.points).astype(np.float64)


def bounding_sphere(points: np.ndarray, keep: float = 99.0) -> tuple[np.ndarray, float]:
    """(centre (3,), radius) of a sphere holding ``keep`` % of the points, metres.

    The centre is the middle of the 1-99 percentile box and the radius the ``keep``-th
    percentile of distances, so a few stray points far away do not shrink the objects.
    """
    if len(points) == 0:
        return np.zeros(3), 0.5
    lo, hi = np.percentile(points, [1.0, 99.0], axis=0)
    c = (lo + hi) / 2
    r = float(np.percentile(np.linalg.norm(points - c, axis=1), keep))
    return c, max(r, 0.02)


def default_camera(data: ViewerData, fov: float = FOV) -> CameraPose:
    """Look at the objects' bounding sphere from the first camera's side, at the distance where
    the sphere fills the view height (times ``MARGIN``); elevation as the first camera's, clamped."""
    c, r = bounding_sphere(object_points(data))
    if data.views:
        d = data.views[0].camera.T_world_camera[:3, 3] - c
    else:
        d = np.array([1.0, -1.0, 1.0])
    horiz = float(np.linalg.norm(d[:2]))
    az = d[:2] / horiz if horiz > 1e-9 else np.array([1.0, 0.0])
    el = float(np.clip(np.arctan2(d[2], horiz), *ELEVATION))
    dist = MARGIN * r / np.sin(fov / 2)
    eye = c + dist * np.array([np.cos(el) * az[0], np.cos(el) * az[1], np.sin(el)])
    return CameraPose(look_at=c, position=eye, fov=float(fov))
