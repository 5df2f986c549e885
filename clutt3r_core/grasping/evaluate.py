"""GraspNet-style evaluation of parallel-jaw grasps against the true scene geometry.

A grasp (``T_world_gripper``, ``width``; gripper boxes from ``GripperGeometry``) on target object
``k`` is judged against the posed meshes, the table (the half-space below ``table_z``) and
any support boxes (a tray):

- **collision**: a finger or the palm overlaps a mesh (a densely sampled surface point inside
  the box, or a box sample point inside a closed mesh), the table, or a support box;
- **holds the target and nothing else**: the closing region contains at least
  ``min_target_samples`` surface samples of the target, none of any other object, and does not
  overlap the table or a support box;
- **contacts**: where the closing fingers, moving along x, first touch the target: the centroid
  and mean face normal of the target's surface samples inside the closing region within
  ``contact_tolerance`` of the smallest (x < 0 finger) and of the largest gripper x;
- **force closure** (two point contacts with friction, the test GraspNet takes from Dex-Net):
  the line between the contacts lies inside both friction cones, i.e. its angle to each inward
  normal is at most ``atan(mu)``. ``min_mu`` is the smallest friction coefficient for which the
  grasp is in force closure (``tan`` of the larger angle; inf when a normal faces away).

``success(mu) = ~collision & holds & (min_mu <= mu)``. GraspNet reports mu = 0.2 ... 1.2.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.grasping.gripper import FRANKA, Box, GripperGeometry, box_grid

__all__ = ["SceneGeometry", "EvalConfig", "GraspEval", "GraspEvaluator", "boxes_overlap", "synth_scene_geometry",
           "GRASPNET_MUS"]

GRASPNET_MUS: tuple[float, ...] = (0.2, 0.4, 0.6, 0.8, 1.0, 1.2)
"""Friction coefficients GraspNet-1Billion reports AP over."""


@dataclass(frozen=True, eq=False)
class SceneGeometry:
    """The true geometry of a scene, world frame, metres.

    Attributes:
        meshes: per object id, (vertices (V, 3) float64, faces (F, 3) int64) posed in the world.
        support_boxes: axis-aligned support boxes (a tray's floor and walls) as (centre (3,), half (3,)).
        table_z: the table is the half-space z < table_z; None = no table.
    """

    meshes: tuple[tuple[np.ndarray, np.ndarray], ...]
    support_boxes: tuple[tuple[np.ndarray, np.ndarray], ...] = ()
    table_z: float | None = 0.0

    def __post_init__(self) -> None:
        for i, (v, f) in enumerate(self.meshes):
            if np.ndim(v) != 2 or np.shape(v)[1] != 3 or np.ndim(f) != 2 or np.shape(f)[1] != 3:
                raise SceneError(f"SceneGeometry: mesh {i} needs vertices (V, 3) and faces (F, 3)")


@dataclass(frozen=True)
class EvalConfig:
    """Settings of the evaluator (ours)."""

    gripper: GripperGeometry = FRANKA
    """The hand of the convention."""
    surface_spacing: float = 0.0015
    """Mean spacing of the surface samples of every mesh, metres (1.5 mm: a surface crossing a
    1 cm finger is sampled ~40 times)."""
    inside_spacing: float = 0.01
    """Spacing of the box sample points tested for lying inside a closed mesh, metres."""
    contact_tolerance: float = 0.001
    """A finger's contact is the centroid (and mean normal) of the target's surface samples within
    this distance of the first touch along x (one sample would pick an arbitrary point of a flat
    face and tilt the line between the contacts), metres."""
    min_target_samples: int = 5
    """Least target surface samples in the closing region for the grasp to hold it."""
    seed: int = 0
    """Seed of the surface sampling."""


@dataclass(frozen=True, eq=False)
class GraspEval:
    """Per-grasp verdicts (G grasps).

    Attributes:
        collision: (G,) bool, a finger or the palm hits a mesh, the table or a support box.
        holds: (G,) bool, the closing region holds the target and nothing else.
        contacts: (G, 2, 3) float64 world contacts (x < 0 finger first); NaN when none.
        min_mu: (G,) float64 least friction coefficient for force closure; inf when never.
    """

    collision: np.ndarray
    holds: np.ndarray
    contacts: np.ndarray
    min_mu: np.ndarray

    def success(self, mu: float) -> np.ndarray:
        return ~self.collision & self.holds & (self.min_mu <= mu)


def _rot_frame(T: np.ndarray, box: Box) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World (centre (3,), rotation (3, 3), half (3,)) of a gripper-frame box under ``T``."""
    return T[:3, :3] @ np.asarray(box.centre) + T[:3, 3], T[:3, :3], np.asarray(box.half, float)


def boxes_overlap(c1, R1, h1, c2, R2, h2, eps: float = 0.0) -> bool:
    """Separating-axis test of two oriented boxes (centre (3,), rotation (3, 3) columns = axes, half (3,)).

    True when they overlap by more than ``eps`` metres along every separating axis candidate.
    """
    A, B = np.asarray(R1, float), np.asarray(R2, float)
    d = np.asarray(c2, float) - np.asarray(c1, float)
    axes = [A[:, i] for i in range(3)] + [B[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            ax = np.cross(A[:, i], B[:, j])
            if np.linalg.norm(ax) > 1e-9:
                axes.append(ax / np.linalg.norm(ax))
    for ax in axes:
        r1 = np.sum(np.abs(A.T @ ax) * h1)
        r2 = np.sum(np.abs(B.T @ ax) * h2)
        if abs(d @ ax) >= r1 + r2 - eps:
            return False
    return True


@dataclass
class GraspEvaluator:
    """Judges grasps on one scene (surface samples and the occupancy test are built once)."""

    geometry: SceneGeometry
    config: EvalConfig = field(default_factory=EvalConfig)

    def __post_init__(self) -> None:
        import open3d as o3d
        import trimesh

        rng_seed = self.config.seed
        pts, nrm, owner = [], [], []
        self._o3d = o3d.t.geometry.RaycastingScene()
        self._spheres = []
        for k, (v, f) in enumerate(self.geometry.meshes):
            m = trimesh.Trimesh(np.asarray(v, float), np.asarray(f, np.int64), process=False)
            n = max(200, int(m.area / self.config.surface_spacing ** 2))
            p, fi = trimesh.sample.sample_surface(m, n, seed=rng_seed + k)
            pts.append(p)
            nrm.append(m.face_normals[fi])
            owner.append(np.full(len(p), k, np.int32))
            c = np.asarray(v).mean(0)
            self._spheres.append((c, float(np.linalg.norm(np.asarray(v) - c, axis=1).max())))
            self._o3d.add_triangles(o3d.core.Tensor(np.asarray(v, np.float32)),
                                    o3d.core.Tensor(np.asarray(f, np.uint32)))
        self._pts = np.concatenate(pts) if pts else np.zeros((0, 3))
        self._nrm = np.concatenate(nrm) if nrm else np.zeros((0, 3))
        self._owner = np.concatenate(owner) if owner else np.zeros(0, np.int32)
        self._starts = np.concatenate([[0], np.cumsum([len(p) for p in pts])]).astype(np.int64)

    def _inside_any_mesh(self, p: np.ndarray) -> np.ndarray:
        import open3d as o3d

        if not len(self.geometry.meshes):
            return np.zeros(len(p), bool)
        occ = self._o3d.compute_occupancy(o3d.core.Tensor(np.asarray(p, np.float32)), nsamples=3)
        return occ.numpy() > 0.5

    def _near_points(self, centre: np.ndarray, radius: float) -> np.ndarray:
        sel = [np.arange(self._starts[k], self._starts[k + 1])
               for k, (c, r) in enumerate(self._spheres) if np.linalg.norm(c - centre) <= r + radius]
        return np.concatenate(sel) if sel else np.zeros(0, np.int64)

    def _box_hits_support(self, T: np.ndarray, box: Box) -> bool:
        c, R, h = _rot_frame(T, box)
        if self.geometry.table_z is not None:
            corners = c + (np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * h) @ R.T
            if corners[:, 2].min() < self.geometry.table_z:
                return True
        return any(boxes_overlap(c, R, h, bc, np.eye(3), bh) for bc, bh in self.geometry.support_boxes)

    def evaluate(self, poses: np.ndarray, widths: np.ndarray, target: int) -> GraspEval:
        """Verdicts for grasps ``poses`` (G, 4, 4) ``T_world_gripper`` at ``widths`` (G,) on object ``target``."""
        g = self.config.gripper
        poses = np.asarray(poses, float).reshape(-1, 4, 4)
        widths = np.asarray(widths, float).reshape(-1)
        G = len(poses)
        coll = np.zeros(G, bool)
        holds = np.zeros(G, bool)
        contacts = np.full((G, 2, 3), np.nan)
        min_mu = np.full(G, np.inf)
        for i in range(G):
            T, w = poses[i], min(float(widths[i]), g.max_width)
            if not w > 0:
                coll[i] = True
                continue
            boxes = g.boxes(w)
            idx = self._near_points(T[:3, 3], g.reach)
            loc = (self._pts[idx] - T[:3, 3]) @ T[:3, :3]
            parts = ("finger_left", "finger_right", "palm")
            hit = any(boxes[n].contains(loc).any() for n in parts)
            if not hit:
                hit = any(self._box_hits_support(T, boxes[n]) for n in parts)
            if not hit:  # a box wholly inside a mesh has no surface sample in it
                samples = np.concatenate([box_grid(boxes[n], self.config.inside_spacing)[0] for n in parts])
                hit = bool(self._inside_any_mesh(samples @ T[:3, :3].T + T[:3, 3]).any())
            coll[i] = hit
            inc = boxes["closing"].contains(loc)
            own = self._owner[idx]
            tgt = inc & (own == target)
            holds[i] = (tgt.sum() >= self.config.min_target_samples and not (inc & (own != target)).any()
                        and not self._box_hits_support(T, boxes["closing"]))
            if tgt.any():
                ti = np.flatnonzero(tgt)
                tol = self.config.contact_tolerance
                xs = loc[ti, 0]
                a = ti[xs <= xs.min() + tol]  # the patch the x < 0 finger touches first
                b = ti[xs >= xs.max() - tol]
                c1, c2 = self._pts[idx[a]].mean(0), self._pts[idx[b]].mean(0)
                contacts[i] = (c1, c2)
                min_mu[i] = _min_mu(c1, _unit(self._nrm[idx[a]].sum(0)), c2, _unit(self._nrm[idx[b]].sum(0)))
        return GraspEval(coll, holds, contacts, min_mu)


def _unit(v: np.ndarray) -> np.ndarray:
    return v / max(float(np.linalg.norm(v)), 1e-12)


def _min_mu(c1: np.ndarray, n1: np.ndarray, c2: np.ndarray, n2: np.ndarray) -> float:
    """Least friction coefficient putting the line c1-c2 inside both friction cones (outward normals n1, n2)."""
    d = c2 - c1
    L = np.linalg.norm(d)
    if L < 1e-9:
        return float("inf")
    u = d / L
    cos1 = float(u @ -n1)  # the force at c1 pushes along u; the inward normal there is -n1
    cos2 = float(-u @ -n2)
    c = min(cos1, cos2)
    if c <= 0:
        return float("inf")
    return float(np.tan(np.arccos(np.clip(c, -1.0, 1.0))))


def synth_scene_geometry(scene_dir: str | Path) -> SceneGeometry:
    """The true geometry of a scene written by ``clutt3r synth``: posed YCB meshes, table z = 0, tray boxes."""
    import json

    from clutt3r_core.synth.generator import load_synth_info
    from clutt3r_core.synth.objects import load_object
    from clutt3r_core.synth.physics import TraySpec, tray_boxes

    root = Path(scene_dir)
    info = load_synth_info(root)
    objs = json.loads((root / "gt" / "objects.json").read_text())
    meshes = []
    for o in objs:
        m = load_object(o["name"])
        T = np.asarray(o["T_world_object"], float)
        meshes.append((m.vertices @ T[:3, :3].T + T[:3, 3], np.asarray(m.faces, np.int64)))
    boxes = []
    if info.config.use_tray:
        # the tray the generator builds (synth/generator.py, generate): centred on the pile centre
        tray = TraySpec(half_x=info.config.radius + 0.11, half_y=info.config.radius + 0.07)
        boxes = [(c + np.asarray(info.centre, float), h) for c, h in tray_boxes(tray)]
    return SceneGeometry(tuple(meshes), tuple(boxes), 0.0)
