"""The built-in analytic antipodal grasp planner (registry: ``grasp_planner`` ``antipodal``).

``plan_antipodal(request, config) -> GraspSet``, a pure function, in five steps:

1. **Contact pairs.** Up to ``max_first_contacts`` target points ``p`` are paired with up to
   ``max_second_contacts`` target points ``q``. The closing axis x of a pair bisects the two
   inward normals (``-n_p`` at p and ``n_q`` seen from p; the fused normals point outwards,
   towards the cameras). A pair is antipodal when x lies within ``pair_angle_deg`` of both
   inward normals, the line p -> q within ``line_angle_deg`` of them (the contacts face each
   other), and the extent ``(q - p) . x`` fits the hand (``min_pair_distance`` ..
   ``max_width - 2 * min_finger_margin``). The best pairs, one per (1 cm centre cell,
   closing-axis bin), are kept (``max_pairs``).
2. **Gripper fit.** The opening is ``(q - p) . x + 2 * finger_margin`` (capped at the hand's
   maximum); the grasp centre starts at the pair's midpoint; the approach z is swept around x in ``approach_steps``
   angles starting from the preferred approach, and the grasp centre is shifted along z by
   each ``depth_offsets`` (positive = deeper: the contacts move towards the palm).
3. **Collisions against the whole fused cloud** (support included). Fingers and the closing
   region are tested exactly: the cloud points near each pair centre (one k-d tree ball query
   per pair) are put into every candidate's gripper frame. A candidate is dropped when any
   point lies in a finger box grown by ``collision_pad``, when the closing region holds fewer
   than ``min_target_points`` target points or more than ``max_foreign_points`` other points
   ("holds the target and nothing else"). The palm, far larger, is tested on a 5 mm distance
   grid (Euclidean distance transform of the occupied cells around the target): each palm
   sample point must be farther from any occupied cell than its cover radius plus the grid's
   worst-case error (``cell * sqrt(3)``) plus ``collision_pad``. This is conservative: the palm
   keeps about 2 cm from everything, never less than ``collision_pad``.
4. **Unseen space.** Space no camera has seen as free is occupied (the hidden backs of
   objects, the inside of the table). A grid cell centre is *unseen-occupied* when at least
   one view sees its pixel (inside the image, valid depth) and *every* view that sees its
   pixel has it more than ``hidden_tolerance`` behind the observed depth. Pixels outside an
   image or on a depth hole say nothing; a cell no view sees is free (nothing can be said about
   it, and the table edge would otherwise close every approach). Finger and palm sample points
   may not fall in an unseen-occupied cell. With no views in the request this step is skipped
   (cloud-only checks, reported in the result's message).
5. **Score and rank.** ``score = sum(w_i * s_i) / sum(w_i)`` with every term in [0, 1]:
   - antipodality ``s_a``: ``(cos a - cos a_max) / (1 - cos a_max)`` with ``a`` the larger of the
     two angles between the closing line and the inward normals (1 = perfectly opposed);
   - approach ``s_p``: ``(1 + z . preferred_approach) / 2`` (1 = straight along the preferred
     direction, from above by default; 0 = the opposite);
   - clearance ``s_c``: the smallest distance from any finger or palm sample point to the cloud
     (distance grid), minus the acceptance threshold of that part, over ``clearance_saturation``,
     clipped to [0, 1] (more room for calibration and pose error);
   - centring ``s_m``: ``exp(-d / centring_scale)`` with ``d`` the distance from the target's
     centroid to the closing axis line (a grasp through the centre of mass resists torque).
   Greedy non-maximum suppression removes near-duplicates (centres within ``nms_distance`` and
   approach and closing axes within ``nms_angle_deg``, the closing axis up to sign since the
   hand is symmetric), then the best ``max_grasps`` are returned, best first.

No grasp found is an empty ``GraspSet`` whose ``message`` says which stage removed the
candidates; nothing raises for a hard scene.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.grasping import GraspRequest, GraspSet
from clutt3r_core.grasping.collision import Grid, distance_grid, palm_and_unseen, unseen_occupied
from clutt3r_core.grasping.gripper import FRANKA, GripperGeometry, box_grid

__all__ = ["AntipodalConfig", "AntipodalPlanner", "plan_antipodal", "unseen_occupied", "PlanStats"]


@dataclass(frozen=True)
class AntipodalConfig:
    """Settings of the antipodal planner (every field ours; the reason is given per field)."""

    gripper: GripperGeometry = FRANKA
    """The hand (docs/conventions.md, "Gripper")."""
    seed: int = 0
    """Seed of the contact subsampling (the result is deterministic for a seed)."""
    max_first_contacts: int = 192
    """First contacts p sampled from the target (bounds the pair matrix; 192 x 1536 pairs ~ 20 ms)."""
    max_second_contacts: int = 1536
    """Second contacts q sampled from the target (a 5 mm cloud of a 15 cm object has ~1500 points)."""
    pair_angle_deg: float = 20.0
    """Largest angle between the closing axis (the bisector of the two inward normals) and either
    inward normal for a pair to count as antipodal (tan 20 deg = 0.36: force closure at friction
    0.36 on the observed normals)."""
    max_normal_spread_deg: float = 15.0
    """Contacts are sampled only where the normals of the 8 nearest target points agree with the
    point's own within this mean angle: the PCA normals of edges and corners average two faces
    and would pair edge to opposite edge across a diagonal (measured on a box: mu 0.7-1.7)."""
    relaxed_angle_deg: float = 40.0
    """When the strict pass finds fewer than ``max_pairs / 4`` pairs, a second pass without the
    smoothness filter admits pairs up to this angle (both gates). On thin and flat objects (a
    marker, a wrench, a sponge lying down) the 5 mm PCA normals of the narrow sides lean towards
    the top face by 30-45 deg, so the strict pass finds nothing; these pairs score 0 on
    antipodality and rank below every strict pair."""
    line_angle_deg: float = 30.0
    """Largest angle between the line p -> q and either inward normal (the contacts must face each
    other across the object; looser than ``pair_angle_deg`` since the axis comes from the normals)."""
    min_pair_distance: float = 0.004
    """Shortest contact distance, metres (thinner than ~a voxel is noise, not an object)."""
    finger_margin: float = 0.006
    """Room between each contact and its finger when the hand closes in, metres (the fused
    surface is within ~3 mm of the true one). Measured against true meshes (oracle targets,
    top-1 success at mu 0.5): 10 mm -> 6 mm raised hard seeds 0-2 from 33 % to 40 %, held-out
    hard seeds 3-4 from 21 % to 31 %, easy + intermediate from 60 % to 62 %."""
    min_finger_margin: float = 0.003
    """Least room per side when the object barely fits the maximum opening, metres."""
    max_pairs: int = 96
    """Contact pairs carried into the gripper fit (the candidate count is this x approaches x depths)."""
    approach_steps: int = 12
    """Approach directions swept around each closing axis (every 30 deg)."""
    depth_offsets: tuple[float, ...] = (0.0, 0.01, -0.01, -0.017)
    """Shifts of the grasp centre along the approach from the contacts' midpoint, metres
    (+: deeper, contacts nearer the palm; -: shallower, fingertips clear of what lies below;
    -0.017 puts the contacts 3 mm from the fingertips, for flat objects lying on the table)."""
    preferred_approach: tuple[float, float, float] = (0.0, 0.0, -1.0)
    """Preferred approach direction in world (default from above: world -z)."""
    min_approach_dot: float = -0.5
    """Approaches with ``z . preferred_approach`` below this are not tried (from below the
    horizontal into a table; saves the collision tests of hopeless candidates)."""
    collision_pad: float = 0.002
    """Growth of the finger boxes and the palm's clearance for cloud collisions, metres
    (fused points are voxel means, up to ~2.5 mm off the surface)."""
    grid_cell: float = 0.005
    """Cell of the distance and unseen-space grids, metres (the fusion voxel, Sec. IV)."""
    palm_spacing: float = 0.01
    """Spacing of the palm's sample points, metres (cover radius ~8.5 mm)."""
    finger_spacing: float = 0.005
    """Spacing of the fingers' sample points for the unseen-space check, metres."""
    hidden_tolerance: float = 0.006
    """A point is hidden in a view when it lies this far behind the observed depth, metres
    (above 1 mm depth quantisation plus a voxel half-diagonal, so the seen surface itself is free)."""
    min_target_points: int = 3
    """Least target points in the closing region (fewer is a glancing touch, not a grasp)."""
    max_foreign_points: int = 0
    """Most non-target points (other objects, table, tray) allowed in the closing region."""
    clearance_saturation: float = 0.02
    """Clearance beyond the acceptance threshold at which the clearance term saturates, metres."""
    centring_scale: float = 0.02
    """Length scale of the centring term, metres (half the width of a typical grasped object)."""
    w_antipodal: float = 0.4
    """Weight of the antipodality term."""
    w_approach: float = 0.25
    """Weight of the approach term."""
    w_clearance: float = 0.15
    """Weight of the clearance term."""
    w_centring: float = 0.2
    """Weight of the centring term."""
    nms_distance: float = 0.01
    """Centres closer than this (metres) with similar axes are duplicates."""
    nms_angle_deg: float = 30.0
    """Axes within this angle are similar (approach; closing axis up to sign)."""
    max_grasps: int = 50
    """Most grasps returned (the palm and unseen tests stop once twice as many candidates passed)."""

    def __post_init__(self) -> None:
        checks = {
            "max_first_contacts": self.max_first_contacts >= 1, "max_second_contacts": self.max_second_contacts >= 1,
            "pair_angle_deg": 0 < self.pair_angle_deg < 90,
            "line_angle_deg": 0 < self.line_angle_deg < 90,
            "max_normal_spread_deg": 0 < self.max_normal_spread_deg <= 180,
            "relaxed_angle_deg": 0 < self.relaxed_angle_deg < 90, "min_pair_distance": self.min_pair_distance >= 0,
            "finger_margin": self.finger_margin >= 0, "min_finger_margin": 0 <= self.min_finger_margin,
            "max_pairs": self.max_pairs >= 1, "approach_steps": self.approach_steps >= 1,
            "collision_pad": self.collision_pad >= 0, "grid_cell": self.grid_cell > 0,
            "palm_spacing": self.palm_spacing > 0, "finger_spacing": self.finger_spacing > 0,
            "hidden_tolerance": self.hidden_tolerance >= 0, "min_target_points": self.min_target_points >= 1,
            "max_foreign_points": self.max_foreign_points >= 0, "clearance_saturation": self.clearance_saturation > 0,
            "centring_scale": self.centring_scale > 0, "max_grasps": self.max_grasps >= 1,
            "nms_angle_deg": 0 <= self.nms_angle_deg <= 180, "nms_distance": self.nms_distance >= 0,
        }
        for name, ok in checks.items():
            if not ok:
                raise SceneError(f"AntipodalConfig.{name} is out of range: {getattr(self, name)}")
        if not self.depth_offsets:
            raise SceneError("AntipodalConfig.depth_offsets needs at least one offset")
        lo, hi = self.gripper.closing_z
        if any(not lo <= -d <= hi for d in self.depth_offsets):
            raise SceneError(f"AntipodalConfig.depth_offsets must keep the contacts in the closing region "
                             f"(|offset| within {self.gripper.closing_z}), got {self.depth_offsets}")
        if np.linalg.norm(self.preferred_approach) < 1e-6:
            raise SceneError("AntipodalConfig.preferred_approach must be a non-zero vector")
        if min(self.w_antipodal, self.w_approach, self.w_clearance, self.w_centring) < 0 or \
                self.w_antipodal + self.w_approach + self.w_clearance + self.w_centring <= 0:
            raise SceneError("AntipodalConfig weights must be >= 0 with a positive sum")


@dataclass(frozen=True)
class PlanStats:
    """How many candidates each stage kept (for messages and the benchmark)."""

    target_points: int = 0
    pairs: int = 0
    candidates: int = 0
    after_fingers: int = 0
    after_closing: int = 0
    after_palm: int = 0
    after_unseen: int = 0
    returned: int = 0
    seconds: dict = field(default_factory=dict)

    def summary(self) -> str:
        return (f"{self.target_points} target points, {self.pairs} antipodal pairs, {self.candidates} candidates; "
                f"kept {self.after_fingers} after finger collisions, {self.after_closing} after the closing-region "
                f"rule, {self.after_palm} after palm collisions, {self.after_unseen} after unseen space")


# ------------------------------------------------------------------------------ the planner


def _unit(v: np.ndarray) -> np.ndarray:
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.maximum(n, 1e-12)


def _sample(n: int, k: int, rng: np.random.Generator) -> np.ndarray:
    return np.arange(n) if n <= k else np.sort(rng.choice(n, k, replace=False))


def _smooth_points(tp: np.ndarray, tn: np.ndarray, max_spread_deg: float, k: int = 8) -> np.ndarray:
    """(T,) bool: the mean angle between a point's normal and its ``k`` nearest neighbours' is small."""
    from scipy.spatial import cKDTree

    if len(tp) <= k:
        return np.ones(len(tp), bool)
    _, nb = cKDTree(tp).query(tp, k=k + 1)
    mean_cos = np.einsum("nk,njk->nj", tn, tn[nb[:, 1:]]).mean(axis=1)
    return mean_cos >= np.cos(np.radians(max_spread_deg))


def _pairs(tp: np.ndarray, tn: np.ndarray, cfg: AntipodalConfig, rng: np.random.Generator, relaxed: bool = False):
    """Antipodal contact pairs (p (P,3), q (P,3), closing axis (P,3), quality cos (P,)), best first,
    one per 1 cm centre cell and closing-axis bin."""
    g = cfg.gripper
    pair_angle = cfg.relaxed_angle_deg if relaxed else cfg.pair_angle_deg
    line_angle = max(cfg.relaxed_angle_deg, cfg.line_angle_deg) if relaxed else cfg.line_angle_deg
    good = np.ones(len(tp), bool) if relaxed else _smooth_points(tp, tn, cfg.max_normal_spread_deg)
    if good.sum() < 2:  # nothing smooth (a tiny or ragged segment): use every point
        good[:] = True
    cand = np.flatnonzero(good)
    ip = cand[_sample(len(cand), cfg.max_first_contacts, rng)]
    iq = cand[_sample(len(cand), cfg.max_second_contacts, rng)]
    P, Np = tp[ip].astype(np.float64), tn[ip].astype(np.float64)
    Q, Nq = tp[iq].astype(np.float64), tn[iq].astype(np.float64)
    d = Q[None, :, :] - P[:, None, :]
    dist = np.linalg.norm(d, axis=2)
    with np.errstate(invalid="ignore", divide="ignore"):
        u = d / dist[..., None]
    cos1 = -np.einsum("pqk,pk->pq", u, Np)  # line vs inward normal at p
    cos2 = np.einsum("pqk,qk->pq", u, Nq)  # line vs inward normal at q (-u . -n_q)
    # the closing axis bisects the two inward normals (-n_p and n_q seen from p): on flat faces and
    # convex surfaces the fingers then close along the surface normal, whatever the exact p and q
    nn = -np.einsum("pk,qk->pq", Np, Nq)  # cos of the angle between -n_p and n_q
    cos_h = np.sqrt(np.clip((1 + nn) / 2, 0, 1))  # cos of half that angle: axis vs each inward normal
    ok = (np.minimum(cos1, cos2) >= np.cos(np.radians(line_angle))) & \
         (cos_h >= np.cos(np.radians(pair_angle))) & (dist >= max(cfg.min_pair_distance, 1e-6)) & \
         (dist <= g.max_width - 2 * cfg.min_finger_margin)
    a, b = np.nonzero(ok)
    if len(a) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0)
    p, q, c = P[a], Q[b], cos_h[a, b]
    axis = _unit(Nq[b] - Np[a])
    # canonical axis sign (the hand is symmetric): first non-negligible component positive
    sgn = np.where(np.abs(axis[:, 0]) > 1e-3, np.sign(axis[:, 0]),
                   np.where(np.abs(axis[:, 1]) > 1e-3, np.sign(axis[:, 1]), np.sign(axis[:, 2])))
    key_c = np.floor((p + q) / 2 / 0.01).astype(np.int64)
    key_c -= key_c.min(0)  # < 20 cells per axis for anything the hand can hold
    key_a = np.rint(axis * sgn[:, None] * 3).astype(np.int64) + 3  # ~20 deg bins, 0..6
    key = ((((key_c[:, 0] * 1024 + key_c[:, 1]) * 1024 + key_c[:, 2]) * 8 + key_a[:, 0]) * 8 + key_a[:, 1]) * 8 \
        + key_a[:, 2]
    # best first; ties (flat faces give many equal pairs) broken at random so the kept pairs spread out
    order = np.lexsort((rng.random(len(c)), -np.round(c, 2)))
    _, first = np.unique(key[order], return_index=True)
    keep = order[np.sort(first)][: cfg.max_pairs]
    return p[keep], q[keep], axis[keep], c[keep]


def plan_antipodal(request: GraspRequest, config: AntipodalConfig = AntipodalConfig()) -> tuple[GraspSet, PlanStats]:
    """Ranked antipodal grasps on the request's target (module docstring). Returns (grasps, stats)."""
    cfg, g = config, config.gripper
    t0 = time.perf_counter()
    secs: dict[str, float] = {}
    rng = np.random.default_rng(cfg.seed)
    inst = request.instance
    tp, tn = request.target_points, request.target_normals
    stats = PlanStats(target_points=len(tp))

    def empty(msg: str, st: PlanStats) -> tuple[GraspSet, PlanStats]:
        return GraspSet.empty(inst, msg), st

    if len(tp) < cfg.min_target_points:
        return empty(f"no grasp: the target has {len(tp)} points (at least {cfg.min_target_points} needed)", stats)
    P, Q, x, qual = _pairs(tp, tn, cfg, rng)
    if len(P) < cfg.max_pairs // 4 and cfg.relaxed_angle_deg > cfg.pair_angle_deg:
        # thin and flat objects: few smooth points and normals bent by the neighbouring faces
        P2, Q2, x2, q2 = _pairs(tp, tn, cfg, rng, relaxed=True)
        n2 = cfg.max_pairs - len(P)
        P, Q, x, qual = (np.concatenate([a, b[:n2]]) for a, b in ((P, P2), (Q, Q2), (x, x2), (qual, q2)))
    secs["pairs"] = time.perf_counter() - t0
    stats = PlanStats(target_points=len(tp), pairs=len(P))
    if len(P) == 0:
        return empty(f"no grasp: no antipodal contact pair on the target's {len(tp)} points fits the hand "
                     f"(opening <= {g.max_width} m, normals within {cfg.pair_angle_deg} deg, relaxed "
                     f"{cfg.relaxed_angle_deg} deg)", stats)

    # -- gripper frames: x closing, z approach swept around x, y = z x x
    mid = (P + Q) / 2
    dist = np.einsum("pk,pk->p", Q - P, x)  # extent of the pair along the closing axis
    width = np.minimum(dist + 2 * cfg.finger_margin, g.max_width)
    pref = _unit(np.asarray(cfg.preferred_approach, float))
    z0 = pref[None] - (x @ pref)[:, None] * x
    bad = np.linalg.norm(z0, axis=1) < 1e-3  # closing axis along the preferred approach
    if bad.any():
        alt = np.cross(x[bad], np.array([1.0, 0.0, 0.0]))
        alt[np.linalg.norm(alt, axis=1) < 1e-3] = np.cross(x[bad], np.array([0.0, 1.0, 0.0]))[
            np.linalg.norm(alt, axis=1) < 1e-3]
        z0[bad] = alt
    z0 = _unit(z0)
    w0 = np.cross(x, z0)
    K, D = cfg.approach_steps, len(cfg.depth_offsets)
    th = 2 * np.pi * np.arange(K) / K
    ct, st = np.cos(th), np.sin(th)
    Z = ct[None, :, None] * z0[:, None] + st[None, :, None] * w0[:, None]  # (P, K, 3)
    Y = -ct[None, :, None] * w0[:, None] + st[None, :, None] * z0[:, None]  # y = z x x
    delta = np.asarray(cfg.depth_offsets, float)
    alive = np.broadcast_to(((Z @ pref) >= cfg.min_approach_dot)[:, :, None], (len(P), K, D)).copy()
    stats = PlanStats(target_points=len(tp), pairs=len(P), candidates=int(alive.sum()))

    # -- exact local tests: cloud points near each pair centre in every candidate frame
    from scipy.spatial import cKDTree

    pts = request.points.astype(np.float64)
    is_t = request.target
    boxes = g.boxes(g.max_width)
    fz0, fz1 = g.finger_z
    cz0, cz1 = g.closing_z
    r_loc = np.sqrt((width / 2 + g.finger_thickness + cfg.collision_pad) ** 2 + (g.finger_half_y + cfg.collision_pad) ** 2
                    + (max(abs(fz0), abs(fz1)) + np.abs(delta).max() + cfg.collision_pad) ** 2)
    pad = cfg.collision_pad
    # the tree only needs the cloud around the target (building it on the whole scene costs more)
    box_lo, box_hi = tp.min(0) - r_loc.max(), tp.max(0) + r_loc.max()
    sub = np.flatnonzero(np.all((pts >= box_lo) & (pts <= box_hi), axis=1))
    tree = cKDTree(pts[sub])
    nb = tree.query_ball_point(mid, r_loc, workers=1)
    lens = np.fromiter((len(n) for n in nb), np.int64, len(nb))
    flat = sub[np.concatenate([np.asarray(n, np.int64) for n in nb])]
    pair_of = np.repeat(np.arange(len(P)), lens)
    dv = pts[flat] - mid[pair_of]
    a = np.einsum("nk,nk->n", dv, x[pair_of])
    b = np.einsum("nk,nk->n", dv, z0[pair_of])
    c = np.einsum("nk,nk->n", dv, w0[pair_of])
    # only points in the slab of the fingers along x and the cylinder they sweep around x matter
    r_yz = np.hypot(g.finger_half_y + pad, max(abs(fz0), abs(fz1)) + np.abs(delta).max() + pad)
    near = (np.abs(a) <= (width / 2)[pair_of] + g.finger_thickness + pad) & (b * b + c * c <= r_yz * r_yz)
    near[np.concatenate([[0], np.cumsum(lens)[:-1]])] = True  # keep one point per pair so segments stay non-empty
    flat, pair_of, a, b, c = flat[near], pair_of[near], a[near], b[near], c[near]
    lens = np.bincount(pair_of, minlength=len(P))
    b, c, ct32, st32 = b.astype(np.float32), c.astype(np.float32), ct.astype(np.float32), st.astype(np.float32)
    ly = -c[:, None] * ct32[None] + b[:, None] * st32[None]  # (n, K)
    lz = b[:, None] * ct32[None] + c[:, None] * st32[None]
    hw = (width / 2)[pair_of]
    absa = np.abs(a)
    starts = np.concatenate([[0], np.cumsum(lens)[:-1]])
    in_y_f = np.abs(ly) <= g.finger_half_y + pad
    in_y_c = np.abs(ly) <= g.finger_half_y
    in_x_f = (absa >= hw - pad) & (absa <= hw + g.finger_thickness + pad)
    in_x_c = absa < hw
    finger_hit = np.zeros((len(P), K, D), bool)
    n_target = np.zeros((len(P), K, D), np.int64)
    n_foreign = np.zeros((len(P), K, D), np.int64)
    for j, dj in enumerate(delta):
        lzj = lz - dj
        f = in_x_f[:, None] & in_y_f & (lzj >= fz0 - pad) & (lzj <= fz1 + pad)
        finger_hit[:, :, j] = np.add.reduceat(f, starts, axis=0) > 0
        cl = in_x_c[:, None] & in_y_c & (lzj >= cz0) & (lzj <= cz1)
        n_target[:, :, j] = np.add.reduceat(cl & is_t[flat][:, None], starts, axis=0)
        n_foreign[:, :, j] = np.add.reduceat(cl & ~is_t[flat][:, None], starts, axis=0)
    alive &= ~finger_hit
    stats = PlanStats(**{**stats.__dict__, "after_fingers": int(alive.sum())})
    alive &= (n_target >= cfg.min_target_points) & (n_foreign <= cfg.max_foreign_points)
    stats = PlanStats(**{**stats.__dict__, "after_closing": int(alive.sum())})
    secs["local"] = time.perf_counter() - t0 - sum(secs.values())
    if not alive.any():
        return empty(f"no grasp: every candidate's fingers hit the cloud or its closing region does not hold "
                     f"only the target ({stats.summary()})", stats)

    # -- partial score (everything but clearance) orders the expensive palm and unseen tests
    ip, ik, ij = np.nonzero(alive)
    R = np.stack([x[ip], Y[ip, ik], Z[ip, ik]], axis=2)  # (C, 3, 3) columns x, y, z
    centre = mid[ip] + delta[ij][:, None] * Z[ip, ik]
    ca = np.cos(np.radians(cfg.pair_angle_deg))
    s_a = np.clip((qual[ip] - ca) / (1 - ca), 0, 1)
    s_p = (1 + R[:, :, 2] @ pref) / 2
    cen = tp.mean(0)
    dv = cen[None] - centre
    d_axis = np.linalg.norm(dv - (dv * R[:, :, 0]).sum(1)[:, None] * R[:, :, 0], axis=1)
    s_m = np.exp(-d_axis / cfg.centring_scale)
    wsum = cfg.w_antipodal + cfg.w_approach + cfg.w_clearance + cfg.w_centring
    partial = (cfg.w_antipodal * s_a + cfg.w_approach * s_p + cfg.w_centring * s_m) / wsum
    order = np.argsort(-partial, kind="stable")

    lo = tp.min(0) - g.reach - np.abs(delta).max() - 2 * cfg.grid_cell
    hi = tp.max(0) + g.reach + np.abs(delta).max() + 2 * cfg.grid_cell
    grid = Grid(lo, cfg.grid_cell, tuple(int(v) for v in np.ceil((hi - lo) / cfg.grid_cell)))
    in_grid = pts[np.all((pts >= lo) & (pts <= hi), axis=1)]
    dgrid = distance_grid(in_grid, grid)
    ptree, ptree_pts = cKDTree(in_grid), in_grid
    secs["grid"] = time.perf_counter() - t0 - sum(secs.values())
    palm_s, palm_r = box_grid(boxes["palm"], cfg.palm_spacing)
    palm_thr = palm_r + cfg.grid_cell * np.sqrt(3) + pad
    palm_depth = np.min(np.asarray(boxes["palm"].half) - np.abs(palm_s - np.asarray(boxes["palm"].centre)), axis=1)
    fl_s, _ = box_grid(boxes["finger_left"], cfg.finger_spacing)
    fr_s = fl_s * np.array([-1.0, 1.0, 1.0])
    unseen_cache = np.full(int(np.prod(grid.shape)), -1, np.int8)
    ok = np.zeros(len(ip), bool)
    clear = np.zeros(len(ip))
    n_palm = 0
    # batches in partial-score order until enough survive (the clearance term only re-ranks survivors)
    for start in range(0, len(order), _BATCH):
        bi = order[start: start + _BATCH]
        ok_b, clear_b, palm_ok = palm_and_unseen(R[bi], centre[bi], width[ip[bi]], grid, dgrid, palm_s, palm_thr,
                                                  palm_depth, ptree, ptree_pts, fl_s, fr_s, request.views, cfg,
                                                  unseen_cache)
        ok[bi], clear[bi] = ok_b, clear_b
        n_palm += int(palm_ok.sum())
        if ok.sum() >= 2 * cfg.max_grasps:
            break
    stats = PlanStats(**{**stats.__dict__, "after_palm": n_palm, "after_unseen": int(ok.sum())})
    secs["palm_unseen"] = time.perf_counter() - t0 - sum(secs.values())
    views = request.views
    if not ok.any():
        why = "palm collisions" if n_palm == 0 else "unseen space (hidden behind surfaces in every view)"
        return empty(f"no grasp: every remaining candidate is blocked by {why} ({stats.summary()})", stats)

    # -- scores
    sel = np.flatnonzero(ok)
    ip, R, centre = ip[sel], R[sel], centre[sel]
    s_c = np.clip(clear[sel] / cfg.clearance_saturation, 0, 1)
    score = partial[sel] + cfg.w_clearance * s_c / wsum

    keep = _nms(score, centre, R, cfg)[: cfg.max_grasps]
    T = np.tile(np.eye(4), (len(keep), 1, 1))
    T[:, :3, :3] = R[keep]
    T[:, :3, 3] = centre[keep]
    contacts = _contacts(tp, T, width[ip[keep]], g, np.stack([P[ip[keep]], Q[ip[keep]]], axis=1))
    secs["score"] = time.perf_counter() - t0 - sum(secs.values())
    secs["total"] = time.perf_counter() - t0
    stats = PlanStats(**{**stats.__dict__, "returned": len(keep), "seconds": secs})
    msg = "" if views else "cloud-only collision checks: no depth views, so unseen space was not checked"
    gs = GraspSet(T, width[ip[keep]].astype(np.float32), score[keep].astype(np.float32),
                  np.full(len(keep), inst, np.int32), contacts, msg)
    return gs, stats


def _contacts(tp: np.ndarray, T: np.ndarray, widths: np.ndarray, g: GripperGeometry, fallback: np.ndarray) -> np.ndarray:
    """(G, 2, 3) float32 expected contacts: the target points in each closing region with the
    smallest and the largest gripper x (where the closing fingers first touch the fused surface;
    the evaluator's definition on the true mesh); the pair's points where the region is empty."""
    out = np.asarray(fallback, np.float32).copy()
    for k in range(len(T)):
        loc = (tp - T[k, :3, 3]) @ T[k, :3, :3]
        inside = np.flatnonzero(g.boxes(float(widths[k]))["closing"].contains(loc))
        if len(inside):
            out[k, 0] = tp[inside[np.argmin(loc[inside, 0])]]
            out[k, 1] = tp[inside[np.argmax(loc[inside, 0])]]
    return out


_BATCH = 384  # candidates per palm/unseen batch (ours: ~2 batches give 2 x max_grasps survivors)


def _nms(score: np.ndarray, centre: np.ndarray, R: np.ndarray, cfg: AntipodalConfig) -> np.ndarray:
    """Indices of kept candidates, best first (greedy; symmetric hand: closing axis up to sign)."""
    order = np.argsort(-score, kind="stable")
    cos_t = np.cos(np.radians(cfg.nms_angle_deg))
    kept: list[int] = []
    suppressed = np.zeros(len(score), bool)
    for i in order:
        if suppressed[i]:
            continue
        kept.append(int(i))
        if len(kept) >= cfg.max_grasps:
            break
        close = np.linalg.norm(centre - centre[i], axis=1) <= cfg.nms_distance
        same_z = R[:, :, 2] @ R[i, :, 2] >= cos_t
        same_x = np.abs(R[:, :, 0] @ R[i, :, 0]) >= cos_t
        suppressed |= close & same_z & same_x
    return np.asarray(kept, np.int64)


class AntipodalPlanner:
    """The default ``grasp_planner``: ``plan_antipodal`` with a fixed config."""

    name = "antipodal"

    def __init__(self, config: AntipodalConfig | None = None) -> None:
        self.config = config or AntipodalConfig()
        self.last_stats: PlanStats | None = None

    def plan(self, request: GraspRequest) -> GraspSet:
        gs, self.last_stats = plan_antipodal(request, self.config)
        return gs
