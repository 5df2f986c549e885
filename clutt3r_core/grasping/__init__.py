"""Grasp poses for a chosen instance: registry kind ``grasp_planner``.

Gripper convention (docs/conventions.md, "Gripper"; numbers in ``gripper.GripperGeometry``):
``T_world_gripper`` (4x4, metres, world z up) has its origin at the grasp centre, the midpoint
between the two finger pads; +z is the approach direction (palm towards fingertips); +x is
the closing axis; y = z x x. ``width`` is the opening between the inner finger faces.

Types here: ``GraspRequest`` (what a planner gets: the whole fused cloud with the target's
points marked, and the depth views for the unseen-space check), ``GraspSet`` (what it
returns: ranked poses, widths, scores) and the ``GraspPlanner`` protocol. The default planner
is ``clutt3r_core.grasping.antipodal.AntipodalPlanner`` (registered as ``antipodal``).

Files: ``GraspSet.save_npz`` / ``GraspSet.load`` (``RUN/grasps.npz``, read by the viewer) and
``GraspSet.to_json`` / ``save_json`` / ``load_json`` (``RUN/grasps.json``, the form
``clutt3r grasp --json`` prints).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.grasping.gripper import FRANKA, GripperGeometry
from clutt3r_core.scene import Camera, check_rigid

__all__ = ["GraspSet", "GraspPlanner", "GraspRequest", "DepthView", "GripperGeometry", "FRANKA",
           "load_base_frame"]


def _ro(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class GraspSet:
    """Ranked parallel-jaw grasps, best first.

    Attributes:
        poses: (G, 4, 4) float64 ``T_world_gripper``; gripper z = approach, x = closing direction.
        widths: (G,) float32 opening in metres.
        scores: (G,) float32 quality, higher is better.
        instance: (G,) int32 target instance, -1 = unknown.
        contacts: optional (G, 2, 3) float32 world points where the planner expects the two
            fingers to touch (x < 0 finger first), metres; None when the planner does not know.
        message: why the set is empty or anything else the user should read ('' = nothing).
    """

    poses: np.ndarray
    widths: np.ndarray
    scores: np.ndarray
    instance: np.ndarray
    contacts: np.ndarray | None = None
    message: str = ""

    def __post_init__(self) -> None:
        g = len(self.scores)
        if np.shape(self.poses) != (g, 4, 4) or np.shape(self.widths) != (g,) or np.shape(self.instance) != (g,):
            raise SceneError("GraspSet: poses (G,4,4), widths (G,), scores (G,), instance (G,) must agree")
        if self.contacts is not None and np.shape(self.contacts) != (g, 2, 3):
            raise SceneError(f"GraspSet: contacts must be ({g}, 2, 3), got {np.shape(self.contacts)}")

    def __len__(self) -> int:
        return len(self.scores)

    @staticmethod
    def empty(instance: int = -1, message: str = "") -> "GraspSet":
        return GraspSet(np.zeros((0, 4, 4)), np.zeros(0, np.float32), np.zeros(0, np.float32),
                        np.zeros(0, np.int32), np.zeros((0, 2, 3), np.float32), message)

    def top(self, n: int) -> "GraspSet":
        """The first ``n`` grasps (the set is ranked best first)."""
        n = max(0, int(n))
        return GraspSet(self.poses[:n], self.widths[:n], self.scores[:n], self.instance[:n],
                        None if self.contacts is None else self.contacts[:n], self.message)

    # -- npz (the viewer's file) -----------------------------------------------------------
    def save_npz(self, path: str | Path) -> Path:
        from clutt3r_core.io.images import atomic_write_npz

        extra = {} if self.contacts is None else {"contacts": np.asarray(self.contacts, np.float32)}
        atomic_write_npz(Path(path), poses=np.asarray(self.poses, np.float64), widths=np.asarray(self.widths, np.float32),
                         scores=np.asarray(self.scores, np.float32), instance=np.asarray(self.instance, np.int32),
                         **extra)
        return Path(path)

    @staticmethod
    def load(path: str | Path) -> "GraspSet":
        """Read ``grasps.npz`` (``save_npz``); ``.json`` paths go to ``load_json``."""
        if str(path).endswith(".json"):
            return GraspSet.load_json(path)
        try:
            z = np.load(path)
            return GraspSet(
                poses=z["poses"].astype(np.float64), widths=z["widths"].astype(np.float32),
                scores=z["scores"].astype(np.float32), instance=z["instance"].astype(np.int32),
                contacts=z["contacts"].astype(np.float32) if "contacts" in z.files else None,
            )
        except (OSError, ValueError, KeyError) as e:
            raise SceneFileError(path, f"not a grasp set ({e})") from None

    # -- json (grasps.json and `clutt3r grasp --json`) ---------------------------------------
    def to_json(self, target: int, query: str | None = None, T_base_world: np.ndarray | None = None,
                step: int | None = None, corrections: dict | None = None) -> dict:
        """``{"target": id, "query": text or null, "grasps": [{"T_world_gripper", "width", "score"}, ...]}``.

        ``step``: for a run with updates, the updates applied to the scene planned in (recorded as
        ``"step"``; absent for a run without updates).

        Best first. With ``T_base_world`` each grasp also carries ``T_base_gripper`` (the robot's
        base frame) and the object gets ``"T_base_world"``; ``T_world_gripper`` stays in world.
        """
        Tb = None if T_base_world is None else check_rigid(T_base_world, "T_base_world")
        grasps = []
        for k in range(len(self)):
            g = {"T_world_gripper": np.asarray(self.poses[k], float).tolist(),
                 "width": float(self.widths[k]), "score": float(self.scores[k])}
            if Tb is not None:
                g["T_base_gripper"] = (Tb @ self.poses[k]).tolist()
            if self.contacts is not None:
                g["contacts"] = np.asarray(self.contacts[k], float).tolist()
            grasps.append(g)
        out: dict = {"target": int(target), "query": query, "grasps": grasps}
        if Tb is not None:
            out["T_base_world"] = Tb.tolist()
        if self.message:
            out["message"] = self.message
        if step is not None:
            out["step"] = int(step)
        if corrections is not None:  # the correction log state the target's ids came from (update.run_labels)
            out["corrections"] = corrections
        return out

    @staticmethod
    def from_json(obj: dict, where: str | Path = "grasps.json") -> "GraspSet":
        try:
            target = int(obj["target"])
            gs = obj["grasps"]
            poses = np.array([g["T_world_gripper"] for g in gs], float).reshape(-1, 4, 4)
            for k, T in enumerate(poses):
                check_rigid(T, f"grasp {k}")
            widths = np.array([g["width"] for g in gs], np.float32)
            scores = np.array([g["score"] for g in gs], np.float32)
            contacts = (np.array([g["contacts"] for g in gs], np.float32).reshape(-1, 2, 3)
                        if gs and all("contacts" in g for g in gs) else None)
        except (KeyError, TypeError, ValueError) as e:
            raise SceneFileError(where, f"not a grasp list ({type(e).__name__}: {e})") from None
        return GraspSet(poses, widths, scores, np.full(len(scores), target, np.int32), contacts,
                        str(obj.get("message", "")))

    def save_json(self, path: str | Path, target: int, query: str | None = None,
                  T_base_world: np.ndarray | None = None, step: int | None = None,
                  corrections: dict | None = None) -> Path:
        from clutt3r_core.io.images import atomic_write_bytes

        atomic_write_bytes(Path(path), json.dumps(self.to_json(target, query, T_base_world, step, corrections),
                                                  indent=1).encode())
        return Path(path)

    @staticmethod
    def load_json(path: str | Path) -> "GraspSet":
        try:
            obj = json.loads(Path(path).read_text())
        except (OSError, ValueError) as e:
            raise SceneFileError(path, f"unreadable grasp file ({e})") from None
        return GraspSet.from_json(obj, path)


def load_base_frame(path: str | Path) -> np.ndarray:
    """Read ``T_base_world`` (4x4 rigid) from ``.json`` (a nested list or ``{"T_base_world": ...}``),
    ``.npy`` or a whitespace text file with 16 numbers."""
    p = Path(path)
    try:
        if p.suffix == ".json":
            obj = json.loads(p.read_text())
            T = obj["T_base_world"] if isinstance(obj, dict) else obj
        elif p.suffix == ".npy":
            T = np.load(p)
        else:
            T = np.loadtxt(p)
        T = np.asarray(T, float).reshape(4, 4)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SceneFileError(p, f"not a 4x4 T_base_world ({type(e).__name__}: {e})") from None
    try:
        return check_rigid(T, "T_base_world")
    except SceneError as e:
        raise SceneFileError(p, str(e)) from None


@dataclass(frozen=True, eq=False)
class DepthView:
    """One posed depth image for the unseen-space check.

    Attributes:
        camera: the pinhole camera (``T_world_camera``, OpenCV axes).
        depth: (H, W) float32 z-depth in metres, NaN = hole.
    """

    camera: Camera
    depth: np.ndarray

    def __post_init__(self) -> None:
        d = np.asarray(self.depth, np.float32)
        if d.shape != (self.camera.height, self.camera.width):
            raise SceneError(f"DepthView: depth {d.shape} does not match the camera "
                             f"{self.camera.height}x{self.camera.width}")
        d = np.where(d > 0, d, np.nan).astype(np.float32)
        object.__setattr__(self, "depth", _ro(d))


@dataclass(frozen=True, eq=False)
class GraspRequest:
    """What a grasp planner gets: the whole scene cloud with the target marked.

    Attributes:
        points: (N, 3) float32 world metres, the whole fused cloud, support (table, tray) included.
        normals: (N, 3) float32 unit normals, oriented towards the cameras (outwards on seen surfaces).
        target: (N,) bool, the points of the object to grasp.
        instance: id of the target instance in its run (-1 = unknown); copied into the result.
        views: posed depth views of the scene; empty = no unseen-space check (cloud only).
        voxel_size: spacing of the cloud in metres (the fused cloud's voxel edge).
    """

    points: np.ndarray
    normals: np.ndarray
    target: np.ndarray
    instance: int = -1
    views: tuple[DepthView, ...] = field(default_factory=tuple)
    voxel_size: float = 0.005

    def __post_init__(self) -> None:
        p = np.asarray(self.points, np.float32)
        if p.ndim != 2 or p.shape[1] != 3:
            raise SceneError(f"GraspRequest.points must be (N, 3), got {p.shape}")
        n = np.asarray(self.normals, np.float32)
        t = np.asarray(self.target)
        if n.shape != p.shape:
            raise SceneError(f"GraspRequest.normals must be {p.shape}, got {n.shape}")
        if t.shape != (p.shape[0],) or t.dtype != bool:
            raise SceneError(f"GraspRequest.target must be ({p.shape[0]},) bool, got {t.dtype} {t.shape}")
        if not np.isfinite(p).all() or not np.isfinite(n).all():
            raise SceneError("GraspRequest: points and normals must be finite")
        if not self.voxel_size > 0:
            raise SceneError(f"GraspRequest.voxel_size must be > 0, got {self.voxel_size}")
        views = tuple(self.views)
        if not all(isinstance(v, DepthView) for v in views):
            raise SceneError("GraspRequest.views must be DepthView objects")
        object.__setattr__(self, "points", _ro(p))
        object.__setattr__(self, "normals", _ro(n))
        object.__setattr__(self, "target", _ro(t))
        object.__setattr__(self, "instance", int(self.instance))
        object.__setattr__(self, "views", views)

    @property
    def target_points(self) -> np.ndarray:
        return self.points[self.target]

    @property
    def target_normals(self) -> np.ndarray:
        return self.normals[self.target]


@runtime_checkable
class GraspPlanner(Protocol):
    """Plans grasps on one instance of a segmented scene (registry kind ``grasp_planner``)."""

    name: str

    def plan(self, request: GraspRequest) -> GraspSet:
        """Ranked grasps on ``request``'s target, best first; an empty set (with a message) when
        none is found, never an exception for a hard scene."""
        ...
