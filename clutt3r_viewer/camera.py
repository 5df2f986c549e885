"""The default camera: the objects (support excluded) filling the view, from the first camera's side."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_viewer.data import ViewerData

__all__ = ["CameraPose", "object_points", "bounding_sphere", "frustum_scale", "default_camera"]

FOV = np.deg2rad(45.0)
"""Vertical field of view of the default camera, radians (ours: narrower than three.js' 75 degrees,
so the pile is seen with little perspective distortion)."""
MARGIN = 1.3
"""Distance factor over the one at which the bounding sphere exactly fills the view height (ours: the
objects stay clear of the control panel, which covers the right ~30 % of a 1280 px wide page)."""
MAX_FRUSTUM_SIZE = 0.06
"""Largest apparent size (frustum scale over its depth, radians) of a camera frustum inside the view
(ours: a nearer frustum hides part of the pile behind its image; measured on a generated tray scene,
the first camera's frustum covered the whole view when the eye sat just behind it)."""
# candidate eyes, tried in order: azimuth turns away from the first camera's (near ones first),
# and for each, fractions of the framing distance (the fov widens to keep the sphere framed)
_AZIMUTH_GROUPS = (np.deg2rad([0.0, 20.0, -20.0, 40.0, -40.0]), np.deg2rad([60.0, -60.0, 90.0, -90.0]))
_DISTANCE_STEPS = (1.0, 0.8, 0.65)


def frustum_scale(data: ViewerData) -> float:
    """Size of the drawn camera frustums, metres: small, their image planes sit above the pile."""
    p = data.seg.points
    ext = float(np.ptp(p, axis=0).max()) if len(p) else 1.0
    return float(np.clip(0.04 * ext, 0.02, 0.06))
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


def _obstruction(eye: np.ndarray, look: np.ndarray, radius: float, frusta: np.ndarray, scale: float) -> float:
    """Apparent size (radians) of the largest camera frustum between ``eye`` and the pile centre
    ``look`` that overlaps the pile's bounding sphere (``radius``) in the image; 0 when none.
    Frusta beyond the centre are ignored (they hide at most the far side of the pile).

    ``frusta``: (F, 3) points of every frustum (apex and image-plane centre), metres.
    """
    v = look - eye
    dist = float(np.linalg.norm(v))
    f = v / dist
    half = np.arcsin(min(radius / dist, 1.0))  # angular radius of the sphere seen from the eye
    worst = 0.0
    for p in frusta:
        w = p - eye
        n = float(np.linalg.norm(w))
        if n < 2 * scale:
            return np.pi  # the eye is (almost) inside a frustum
        depth = float(w @ f)
        if depth <= 0 or depth >= dist:
            continue  # behind the eye, or beyond the pile centre
        off = np.arccos(np.clip(depth / n, -1, 1))
        if off < half + np.arctan(scale / depth):
            worst = max(worst, scale / depth)
    return worst


def default_camera(data: ViewerData, fov: float = FOV) -> CameraPose:
    """Look at the objects' bounding sphere from the first camera's side, at the distance where
    the sphere fills the view height (times ``MARGIN``); elevation as the first camera's, clamped.

    When a camera frustum would loom large in the view (the first camera's own, typically: the
    generator's cameras sit about as far from the pile as the framing distance), the azimuth
    turns away from the first camera in steps, then the eye moves closer with a wider field
    of view (the sphere stays framed), until no frustum does.
    """
    c, r = bounding_sphere(object_points(data))
    cams = np.stack([v.camera.T_world_camera[:3, 3] for v in data.views]) if data.views else np.zeros((0, 3))
    d = cams[0] - c if len(cams) else np.array([1.0, -1.0, 1.0])
    scale = frustum_scale(data)
    # each frustum by its apex and its image plane (``scale`` along the optical axis, z)
    frusta = np.concatenate([cams] + [[v.camera.T_world_camera[:3, 3] + scale * v.camera.T_world_camera[:3, 2]
                                       for v in data.views]]) if data.views else cams
    horiz = float(np.linalg.norm(d[:2]))
    az0 = float(np.arctan2(d[1], d[0])) if horiz > 1e-9 else 0.0
    el = float(np.clip(np.arctan2(d[2], horiz), *ELEVATION))
    dist0 = MARGIN * r / np.sin(fov / 2)
    best: tuple[float, CameraPose] | None = None
    for steps in _AZIMUTH_GROUPS:
        for k, step in ((k, a) for k in _DISTANCE_STEPS for a in steps):
            dist = k * dist0
            fov_k = float(2 * np.arcsin(min(MARGIN * r / dist, 0.99)))
            az = az0 + step
            eye = c + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
            pose = CameraPose(look_at=c, position=eye, fov=fov_k)
            ob = _obstruction(eye, c, r, frusta, scale)
            if ob <= MAX_FRUSTUM_SIZE:
                return pose
            if best is None or ob < best[0]:
                best = (ob, pose)
    assert best is not None
    return best[1]  # a frustum in the way from every candidate: the least obstructed one
