"""Physics piles: drop objects onto a table or into a tray with pybullet and let them settle.

World frame: z up, the table top is the plane z = 0. A tray, when present, is a floor
slab lying on the table plus four walls, all axis-aligned boxes centred on the pile
centre; the same boxes are rendered as background (``tray_boxes``).

Every object is a convex hull (``SynthObject.hull_points``) in Bullet; pybullet runs in
DIRECT mode (no GUI, single thread), so a pile is deterministic for its inputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clutt3r_core.synth.objects import SynthObject

__all__ = ["TraySpec", "PhysicsConfig", "Pile", "tray_boxes", "settle_pile", "resettle_object",
           "random_rotation", "pose_matrix"]


@dataclass(frozen=True)
class TraySpec:
    """A rectangular tray on the table, centred on the pile centre.

    Attributes:
        half_x: inner half length along world x, metres.
        half_y: inner half width along world y, metres.
        wall_height: wall height above the table, metres.
        wall_thickness: metres.
        floor_thickness: metres; the tray floor top is at z = floor_thickness.
        color: (r, g, b) tray colour.
    """

    half_x: float = 0.22
    half_y: float = 0.17
    wall_height: float = 0.06
    wall_thickness: float = 0.012
    floor_thickness: float = 0.008
    color: tuple[int, int, int] = (70, 95, 120)


@dataclass(frozen=True)
class PhysicsConfig:
    """Simulation parameters (all ours: chosen so 20 objects settle in about a second of CPU).

    Attributes:
        timestep: Bullet step, seconds (1/240 is the pybullet default).
        max_time: simulated seconds before giving up on settling.
        min_time: simulated seconds before the settle test is applied.
        settle_lin: a pile is settled when every speed is below this, m/s.
        settle_ang: ... and every angular speed below this, rad/s.
        friction: lateral friction coefficient of objects, table and tray.
        rolling_friction: rolling friction (keeps fruit and balls from rolling away), metres.
        damping: linear and angular damping of objects (ours: speeds up settling).
        table_half: objects whose centre ends farther than this from the pile centre
            (or below the table) fell off and are dropped, metres.
        drop_height: height of the lowest spawn above the floor, metres.
        corral_margin: objects first settle inside a temporary ring of walls of radius
            ``pile_radius + corral_margin`` (removed afterwards, then the pile settles again),
            which makes a compact, leaning pile instead of a scatter; None disables it, metres.
    """

    timestep: float = 1.0 / 240.0
    max_time: float = 4.0
    min_time: float = 0.6
    settle_lin: float = 0.01
    settle_ang: float = 0.1
    friction: float = 0.7
    rolling_friction: float = 0.002
    damping: float = 0.1
    table_half: float = 0.45
    drop_height: float = 0.04
    corral_margin: float | None = 0.04


@dataclass(frozen=True, eq=False)
class Pile:
    """Result of a simulation.

    Attributes:
        poses: (N, 4, 4) float64 T_world_object of every input object (settled).
        kept: (N,) bool, False for objects that fell off the table or out of the tray.
        sim_time: simulated seconds until settled.
        settled: whether the settle test passed before ``max_time``.
    """

    poses: np.ndarray
    kept: np.ndarray
    sim_time: float
    settled: bool


def tray_boxes(tray: TraySpec) -> list[tuple[np.ndarray, np.ndarray]]:
    """The tray as axis-aligned boxes (centre (3,), half extents (3,)), relative to the pile centre.

    Floor first, then the four walls; walls stand on the table (z from 0 to wall_height).
    """
    t, h = tray.wall_thickness, tray.wall_height
    hx, hy = tray.half_x, tray.half_y
    ft = tray.floor_thickness
    return [
        (np.array([0.0, 0.0, ft / 2]), np.array([hx, hy, ft / 2])),
        (np.array([hx + t / 2, 0.0, h / 2]), np.array([t / 2, hy + t, h / 2])),
        (np.array([-hx - t / 2, 0.0, h / 2]), np.array([t / 2, hy + t, h / 2])),
        (np.array([0.0, hy + t / 2, h / 2]), np.array([hx, t / 2, h / 2])),
        (np.array([0.0, -hy - t / 2, h / 2]), np.array([hx, t / 2, h / 2])),
    ]


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random (3, 3) rotation (from a uniform unit quaternion)."""
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    return _quat_to_matrix(q)


def _quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """(x, y, z, w) quaternion (pybullet order) to a (3, 3) rotation."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def _matrix_to_quat(R: np.ndarray) -> list[float]:
    from scipy.spatial.transform import Rotation

    return [float(c) for c in Rotation.from_matrix(R).as_quat()]  # (x, y, z, w)


def pose_matrix(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def _orthonormalise(R: np.ndarray) -> np.ndarray:
    u, _, vt = np.linalg.svd(R)
    return u @ vt


class _World:
    """A pybullet DIRECT client with the table (and tray); closed by ``close``."""

    def __init__(self, cfg: PhysicsConfig, centre: np.ndarray, tray: TraySpec | None) -> None:
        import pybullet as pb

        self.pb = pb
        self.cfg = cfg
        self.cid = pb.connect(pb.DIRECT)
        c = self.cid
        pb.setGravity(0, 0, -9.81, physicsClientId=c)
        pb.setPhysicsEngineParameter(fixedTimeStep=cfg.timestep, numSolverIterations=30,
                                     deterministicOverlappingPairs=1, physicsClientId=c)
        plane = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=c)
        self.static = [pb.createMultiBody(0, plane, physicsClientId=c)]
        if tray is not None:
            for bc, he in tray_boxes(tray):
                s = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=he.tolist(), physicsClientId=c)
                pos = (bc + np.array([centre[0], centre[1], 0.0])).tolist()
                self.static.append(pb.createMultiBody(0, s, basePosition=pos, physicsClientId=c))
        for b in self.static:
            pb.changeDynamics(b, -1, lateralFriction=cfg.friction, physicsClientId=c)

    def add(self, obj: SynthObject, T: np.ndarray, dynamic: bool = True) -> int:
        pb, c = self.pb, self.cid
        shape = pb.createCollisionShape(pb.GEOM_MESH, vertices=obj.hull_points.tolist(), physicsClientId=c)
        body = pb.createMultiBody(obj.mass if dynamic else 0.0, shape, basePosition=T[:3, 3].tolist(),
                                  baseOrientation=_matrix_to_quat(T[:3, :3]), physicsClientId=c)
        pb.changeDynamics(body, -1, lateralFriction=self.cfg.friction, rollingFriction=self.cfg.rolling_friction,
                          spinningFriction=self.cfg.rolling_friction, linearDamping=self.cfg.damping,
                          angularDamping=self.cfg.damping, physicsClientId=c)
        return body

    def run(self, bodies: list[int]) -> tuple[float, bool]:
        """Step until every body in ``bodies`` is slow or ``max_time`` passed."""
        pb, c, cfg = self.pb, self.cid, self.cfg
        steps, chunk = 0, 24
        max_steps = int(round(cfg.max_time / cfg.timestep))
        min_steps = int(round(cfg.min_time / cfg.timestep))
        while steps < max_steps:
            for _ in range(chunk):
                pb.stepSimulation(physicsClientId=c)
            steps += chunk
            if steps < min_steps:
                continue
            slow = True
            for b in bodies:
                lin, ang = pb.getBaseVelocity(b, physicsClientId=c)
                if np.linalg.norm(lin) > cfg.settle_lin or np.linalg.norm(ang) > cfg.settle_ang:
                    slow = False
                    break
            if slow:
                return steps * cfg.timestep, True
        return steps * cfg.timestep, False

    def pose(self, body: int) -> np.ndarray:
        pos, quat = self.pb.getBasePositionAndOrientation(body, physicsClientId=self.cid)
        return pose_matrix(_orthonormalise(_quat_to_matrix(np.asarray(quat))), np.asarray(pos))

    def close(self) -> None:
        self.pb.disconnect(physicsClientId=self.cid)


def _corral(world: _World, centre: np.ndarray, radius: float, height: float, n: int = 16) -> list[int]:
    """A static ring of ``n`` wall boxes (inner radius ``radius``) around ``centre``."""
    pb, c = world.pb, world.cid
    half_len = radius * np.tan(np.pi / n) + 0.01
    walls = []
    for i in range(n):
        a = 2 * np.pi * i / n
        pos = [centre[0] + (radius + 0.01) * np.cos(a), centre[1] + (radius + 0.01) * np.sin(a), height / 2]
        shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.01, half_len, height / 2], physicsClientId=c)
        quat = pb.getQuaternionFromEuler([0, 0, a])
        body = pb.createMultiBody(0, shape, basePosition=pos, baseOrientation=quat, physicsClientId=c)
        pb.changeDynamics(body, -1, lateralFriction=0.2, physicsClientId=c)
        walls.append(body)
    return walls


def _inside(p: np.ndarray, centre: np.ndarray, tray: TraySpec | None, cfg: PhysicsConfig) -> bool:
    d = p[:2] - centre[:2]
    if p[2] < -0.02:
        return False
    if tray is not None:
        return abs(d[0]) <= tray.half_x + 0.005 and abs(d[1]) <= tray.half_y + 0.005
    return float(np.linalg.norm(d)) <= cfg.table_half


def settle_pile(
    objects: Sequence[SynthObject],
    rng: np.random.Generator,
    *,
    centre: np.ndarray = np.zeros(3),
    pile_radius: float = 0.12,
    tray: TraySpec | None = None,
    cfg: PhysicsConfig = PhysicsConfig(),
) -> Pile:
    """Drop ``objects`` from random poses above a disc of ``pile_radius`` around ``centre`` and settle.

    Objects are spawned one above the other (each clear of the previous ones by its
    bounding-sphere radius) with uniformly random orientations, then simulated together
    until every object is slow. Objects that end outside the tray or off the table are
    marked ``kept = False``.
    """
    centre = np.asarray(centre, np.float64)
    floor = tray.floor_thickness if tray is not None else 0.0
    world = _World(cfg, centre, tray)
    try:
        bodies, z = [], floor + cfg.drop_height
        for obj in objects:
            r = obj.radius
            ang, rad = rng.uniform(0, 2 * np.pi), pile_radius * np.sqrt(rng.uniform())
            xy = centre[:2] + rad * np.array([np.cos(ang), np.sin(ang)])
            if tray is not None:  # spawn inside the walls
                xy = np.clip(xy, centre[:2] - [tray.half_x - r * 0.5, tray.half_y - r * 0.5],
                             centre[:2] + [tray.half_x - r * 0.5, tray.half_y - r * 0.5])
            z += r
            bodies.append(world.add(obj, pose_matrix(random_rotation(rng), np.array([xy[0], xy[1], z]))))
            z += r + 0.005
        walls = []
        if cfg.corral_margin is not None:
            walls = _corral(world, centre, pile_radius + cfg.corral_margin, z + 0.1)
        sim_time, settled = world.run(bodies)
        if walls:
            for w in walls:
                world.pb.removeBody(w, physicsClientId=world.cid)
            t2, settled = world.run(bodies)
            sim_time += t2
        poses = np.stack([world.pose(b) for b in bodies]) if bodies else np.zeros((0, 4, 4))
    finally:
        world.close()
    kept = np.array([_inside(T[:3, 3], centre, tray, cfg) for T in poses], bool)
    return Pile(poses, kept, sim_time, settled)


def resettle_object(
    objects: Sequence[SynthObject],
    poses: np.ndarray,
    present: np.ndarray,
    moved: int,
    T_move: np.ndarray,
    *,
    centre: np.ndarray = np.zeros(3),
    tray: TraySpec | None = None,
    lift: float = 0.01,
    cfg: PhysicsConfig = PhysicsConfig(),
) -> np.ndarray:
    """Move object ``moved`` by the world-frame rigid ``T_move`` (lifted by ``lift``) and let it fall.

    Every other present object is static at its pose (nothing else moves), so the only
    change is the displaced object; returns its settled (4, 4) T_world_object.
    """
    world = _World(cfg, np.asarray(centre, np.float64), tray)
    try:
        for i, obj in enumerate(objects):
            if present[i] and i != moved:
                world.add(obj, poses[i], dynamic=False)
        T0 = T_move @ poses[moved]
        T0 = T0.copy()
        T0[2, 3] += lift
        b = world.add(objects[moved], T0)
        world.run([b])
        return world.pose(b)
    finally:
        world.close()
