"""Picking points in 3D for the Edit tab: pure functions, testable without a browser.

viser 1.1 gives the server a click as a world ray (``scene.on_click``: origin, direction) and
a box as a screen rectangle (``scene.on_rect_select``: corners in [0, 1], OpenCV image axes,
(0, 0) the upper-left). The browser's camera is known on the server (``client.camera``:
position, orientation ``wxyz`` = R_world_camera in OpenCV axes, vertical ``fov``, ``aspect``).

* ``pick_along_ray``: the nearest *visible* point the ray passes close to (within a cone of
  ``cone_deg`` around the ray, at least ``min_radius_m``): the front-most such point, so a
  click never selects something behind the surface it hit.
* ``visible_in_rect``: the points inside the rectangle that are *visible*: a z-buffer of the
  candidate points at a coarse resolution (``grid`` cells across; one cell is a few screen
  pixels, so a surface's points cover their cells) keeps a point when it is within
  ``depth_tol`` of its cell's nearest depth. Points behind a surface are left out.
* ``supervoxel_adjacency`` / ``grow``: super-voxels touching (points within ``radius_m``) and
  growing a selection to its neighbours.

All points are world metres; masks are (N,) bool over the same point array.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ScreenCamera", "pick_along_ray", "visible_in_rect", "supervoxel_adjacency", "grow",
           "expand_to_supervoxels"]


@dataclass(frozen=True, eq=False)
class ScreenCamera:
    """The browser's camera at an event.

    Attributes:
        position: (3,) camera centre, world metres.
        R_world_camera: (3, 3) rotation, OpenCV axes (x right, y down, z forward).
        fov_y: vertical field of view, radians.
        aspect: canvas width / height.
    """

    position: np.ndarray
    R_world_camera: np.ndarray
    fov_y: float
    aspect: float

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", np.asarray(self.position, np.float64).reshape(3))
        R = np.asarray(self.R_world_camera, np.float64)
        if R.shape != (3, 3):
            raise ValueError(f"ScreenCamera: R_world_camera must be (3, 3), got {R.shape}")
        object.__setattr__(self, "R_world_camera", R)
        if not (0 < self.fov_y < np.pi and self.aspect > 0):
            raise ValueError("ScreenCamera: fov_y in (0, pi) radians and aspect > 0")

    @staticmethod
    def from_viser(cam) -> "ScreenCamera":
        """From a ``viser.CameraHandle`` (``client.camera``)."""
        import viser.transforms as vtf

        R = vtf.SO3(np.asarray(cam.wxyz, np.float64)).as_matrix()
        return ScreenCamera(np.asarray(cam.position), R, float(cam.fov), float(cam.aspect))

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, v, z): screen coordinates in [0, 1] (OpenCV image axes) and depth (metres along
        the view axis) of world ``points`` (N, 3). z <= 0: behind the camera."""
        pc = (np.asarray(points, np.float64) - self.position) @ self.R_world_camera
        z = pc[:, 2]
        t = np.tan(self.fov_y / 2)
        with np.errstate(divide="ignore", invalid="ignore"):
            u = 0.5 + pc[:, 0] / z / (2 * t * self.aspect)
            v = 0.5 + pc[:, 1] / z / (2 * t)
        return u, v, z

    def ray(self, u: float, v: float) -> tuple[np.ndarray, np.ndarray]:
        """(origin, unit direction) of the world ray through screen point (u, v) (tests, synthetic events)."""
        t = np.tan(self.fov_y / 2)
        d = np.array([(u - 0.5) * 2 * t * self.aspect, (v - 0.5) * 2 * t, 1.0])
        d = self.R_world_camera @ d
        return self.position.copy(), d / np.linalg.norm(d)


def pick_along_ray(points: np.ndarray, origin, direction, candidates: np.ndarray | None = None,
                   cone_deg: float = 0.6, min_radius_m: float = 0.004) -> int:
    """Index of the front-most point within the pick cone of the ray, -1 when none.

    ``candidates``: (N,) bool, the points that can be picked (displayed, not hidden); others
    neither get picked nor block. The cone (``cone_deg`` half-angle, ours: about 8 px at a
    1000 px wide 60 deg view) is widened to ``min_radius_m`` near the camera.
    """
    p = np.asarray(points, np.float64)
    o = np.asarray(origin, np.float64).reshape(3)
    d = np.asarray(direction, np.float64).reshape(3)
    d = d / np.linalg.norm(d)
    idx = np.arange(len(p)) if candidates is None else np.flatnonzero(candidates)
    if len(idx) == 0:
        return -1
    rel = p[idx] - o
    t = rel @ d
    perp = np.linalg.norm(rel - t[:, None] * d, axis=1)
    ok = (t > 0) & (perp <= np.maximum(t * np.tan(np.radians(cone_deg)), min_radius_m))
    if not ok.any():
        return -1
    # front-most hit; among points at about the same depth (one surface) the one nearest the ray
    ts = t[ok]
    near = ts <= ts.min() + max(min_radius_m, 2 * float(perp[ok].min()))
    j = np.flatnonzero(ok)[near]
    return int(idx[j[np.argmin(perp[j])]])


def visible_in_rect(points: np.ndarray, camera: ScreenCamera, screen_min, screen_max,
                    candidates: np.ndarray | None = None, grid: int = 192, depth_tol_m: float = 0.01,
                    depth_tol_rel: float = 0.01) -> np.ndarray:
    """(N,) bool: the candidate points inside the screen rectangle that are visible (module docstring).

    ``grid``: z-buffer cells across the canvas (ours: ~5 px cells at 1000 px, about the size of
    one drawn point, so a surface covers its cells and what lies behind it finds them taken).
    A point is visible when its depth <= its cell's nearest depth + ``depth_tol_m`` +
    ``depth_tol_rel`` x depth (one surface's thickness: points of a 5 mm cloud, tilted).
    """
    p = np.asarray(points, np.float64)
    n = len(p)
    out = np.zeros(n, bool)
    cand = np.ones(n, bool) if candidates is None else np.asarray(candidates, bool)
    u, v, z = camera.project(p)
    gw = int(grid)
    gh = max(1, int(round(gw / camera.aspect)))
    on = cand & (z > 1e-6) & (u >= 0) & (u < 1) & (v >= 0) & (v < 1)
    i = np.flatnonzero(on)
    if len(i) == 0:
        return out
    cell = (np.floor(v[i] * gh).astype(np.int64) * gw + np.floor(u[i] * gw).astype(np.int64))
    zbuf = np.full(gw * gh, np.inf)
    np.minimum.at(zbuf, cell, z[i])
    vis = z[i] <= zbuf[cell] + depth_tol_m + depth_tol_rel * z[i]
    (u0, v0), (u1, v1) = np.minimum(screen_min, screen_max), np.maximum(screen_min, screen_max)
    inside = (u[i] >= u0) & (u[i] <= u1) & (v[i] >= v0) & (v[i] <= v1)
    out[i[vis & inside]] = True
    return out


def supervoxel_adjacency(points: np.ndarray, sv_labels: np.ndarray, radius_m: float = 0.0075) -> np.ndarray:
    """(E, 2) int64 unique pairs (a < b) of super-voxels with points within ``radius_m``
    (ours: 1.5x the pipeline's 5 mm voxel: face-adjacent voxels, not diagonal gaps)."""
    from scipy.spatial import cKDTree

    pairs = cKDTree(np.asarray(points, np.float64)).query_pairs(radius_m, output_type="ndarray")
    sv = np.asarray(sv_labels, np.int64)
    a, b = sv[pairs[:, 0]], sv[pairs[:, 1]]
    diff = a != b
    e = np.stack([np.minimum(a, b)[diff], np.maximum(a, b)[diff]], 1)
    return np.unique(e, axis=0) if len(e) else np.zeros((0, 2), np.int64)


def expand_to_supervoxels(mask: np.ndarray, sv_labels: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: every (candidate) point of each super-voxel that ``mask`` touches."""
    sv = np.asarray(sv_labels, np.int64)
    lut = np.zeros(int(sv.max()) + 1 if len(sv) else 0, bool)
    lut[sv[np.asarray(mask, bool)]] = True
    out = lut[sv]
    return out if candidates is None else out & candidates


def grow(mask: np.ndarray, sv_labels: np.ndarray, adjacency: np.ndarray, candidates: np.ndarray | None = None) -> np.ndarray:
    """(N,) bool: ``mask``'s super-voxels plus their neighbours in ``adjacency`` (whole super-voxels)."""
    sv = np.asarray(sv_labels, np.int64)
    ks = int(sv.max()) + 1 if len(sv) else 0
    lut = np.zeros(ks, bool)
    lut[sv[np.asarray(mask, bool)]] = True
    adj = np.asarray(adjacency, np.int64).reshape(-1, 2)
    add = np.zeros(ks, bool)
    add[adj[lut[adj[:, 0]], 1]] = True
    add[adj[lut[adj[:, 1]], 0]] = True
    out = (lut | add)[sv]
    return out if candidates is None else out & candidates
