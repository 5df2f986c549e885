"""Final refinement of a depth registration: symmetric point-to-plane ICP (ours, session 7).

``depth.register`` aligns the mask's depth points (*scene*) to the stored instance points
(*model*) one way only: every scene point is pulled to its nearest model point, never the
reverse, and its last correspondences reach 1.5 cm (``1.5 x in_place_tol``). Both views are
partial (the stored cloud is what the initial views saw, the new view shows one side), so the
one-way objective is biased: scene points on a face the stored cloud lacks pull towards the
nearest rim, and model points the camera should see on the observed surface are never pulled
to it. Measured on the displaced objects' registrations captured on the generated pairs
(docs/update.md "Session 7: rotation"): the true pose is often *closer* to the observed surface
than the registered one (free-space consistency 0.92-0.98 vs 0.71-0.78 on the worst: hard_1100,
easy_1102, intermediate_1903, intermediate_300), a residual of 4-9 deg at 0.1-0.8 cm.

``refine_registration`` starts from the registered pose and minimises, with Gauss-Newton on a
small rotation about the moved model's centroid and a translation, the sum of two
point-to-plane terms (each the mean over its pairs, so neither side outweighs the other by
its point count):

- scene -> model: each scene point and its nearest moved model point (the ICP's own pairs);
- model -> scene (projective): each moved model point that faces the camera (outward normal,
  from the model's centroid) and whose pixel's new depth lies within the radius of it, and the
  depth point on the same ray (the observed surface where that model point should be).

Residuals use the model's normals (``RegistrationModel.normals``, oriented outwards). The pair
radius shrinks linearly from ``radius_start`` (the ICP's last radius: the refinement starts
from the pairs the ICP ended with) to ``radius_end`` (about 3x the 1.7 mm noise floor of the
stored-to-observed distance measured at the true poses). Pure numpy, one OpenMP thread (as
``register``), ~12 ms per call on 250 scene points and a 1500-point model.

Both terms can agree on a wrong pose (a partial stored cloud; a can whose side normals leave its
tilt loosely held; a box face sliding along its rim), so ``refined_registration`` keeps the
refined pose only when a measure the objective does not use, ``pose_quality`` (free-space
consistency minus 2x the colour error), is not worse by more than a margin; ``flip_check``
demands a larger colour gain for a half turn that maps the stored points onto themselves
(``half_turn_symmetric``). Measured in docs/update.md, "Session 7: refinement regressions".
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from clutt3r_core.normals import _one_openmp_thread
from clutt3r_core.scene import Camera
from clutt3r_core.update.depth import RegistrationModel, _consistency, _depth_at

__all__ = ["Refinement", "flip_check", "half_turn_symmetric", "pose_quality", "refine_registration",
           "refined_registration"]


@dataclass(frozen=True, eq=False)
class Refinement:
    """The refined motion and its iterations.

    Attributes:
        T_world: (4, 4) motion of the stored points, ``p_new = T_world @ p_old``.
        path: (I, 4, 4) the motion after each iteration (the last = ``T_world``); I = 0 when
            no iteration had enough pairs (``T_world`` is then the start).
        cost: (I,) metres: the mean scene-to-model distance, truncated at the iteration's
            radius, before each iteration's step (``Registration.path_cost``'s measure).
    """

    T_world: np.ndarray
    path: np.ndarray
    cost: np.ndarray

    def __post_init__(self):
        if self.T_world.shape != (4, 4) or self.path.ndim != 3 or self.path.shape[1:] != (4, 4) \
                or self.cost.shape != (len(self.path),):
            raise ValueError(f"Refinement: T_world {self.T_world.shape} must be (4, 4), path {self.path.shape} "
                             f"(I, 4, 4) and cost {self.cost.shape} (I,)")


def _outward(points: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """Normals flipped to point away from the points' centroid (PCA normals have no sign)."""
    s = np.sign(((points - points.mean(axis=0)) * normals).sum(axis=1))
    s[s == 0] = 1.0
    return normals * s[:, None]


def refine_registration(model: RegistrationModel, scene: np.ndarray, T_world: np.ndarray, camera: Camera,
                        depth: np.ndarray, *, iterations: int = 15, radius_start: float = 0.015,
                        radius_end: float = 0.005, min_pairs: int = 10) -> Refinement:
    """Refine ``T_world`` (model -> world, (4, 4)) against ``scene`` ((n, 3) world metres, the
    registration's depth points) and the new ``depth`` ((H, W) metres) by the symmetric
    point-to-plane objective of the module docstring. An iteration with fewer than
    ``min_pairs`` scene -> model pairs stops the refinement (the pose is kept as it is)."""
    T = np.array(T_world, np.float64)
    pts, tree = model.points, model.tree
    normals = _outward(pts, model.normals)
    cam_c = camera.T_world_camera[:3, 3]
    scene = np.asarray(scene, np.float64)
    path, cost = [], []
    with _one_openmp_thread():
        for it in range(iterations):
            r = radius_start + (radius_end - radius_start) * it / max(iterations - 1, 1)
            R, t = T[:3, :3], T[:3, 3]
            # scene -> model pairs, found in the model's frame (its k-d tree)
            dist, j = tree.query(np.ascontiguousarray((scene - t) @ R), distance_upper_bound=r)
            ok = np.isfinite(dist)
            if ok.sum() < min_pairs:
                break
            j = j[ok]
            M = pts @ R.T + t
            N = normals @ R.T
            c = M.mean(axis=0)
            P, Np = M[j], N[j]
            J = [np.concatenate([np.cross(P - c, Np), Np], axis=1)]
            res = [((scene[ok] - P) * Np).sum(axis=1)]
            w = [np.full(len(P), 1.0 / len(P))]
            # model -> observed surface (projective): facing points with the new depth near them
            uv, z = camera.project(M)
            d = _depth_at(depth, uv)
            on = np.isfinite(d) & (z > 0) & (np.abs(d - z) <= r) & (((cam_c - M) * N).sum(axis=1) > 0)
            if on.any():
                Q = camera.pixels_to_world(uv[on, 0], uv[on, 1], d[on])  # the observed point on M's ray
                J.append(np.concatenate([np.cross(M[on] - c, N[on]), N[on]], axis=1))
                res.append(((Q - M[on]) * N[on]).sum(axis=1))
                w.append(np.full(int(on.sum()), 1.0 / int(on.sum())))
            cost.append(float(np.minimum(dist, r).mean()))
            Jm, rm, wm = np.concatenate(J), np.concatenate(res), np.concatenate(w)
            Jw = Jm * wm[:, None]
            x = np.linalg.solve(Jw.T @ Jm + 1e-9 * np.eye(6), Jw.T @ rm)
            dR = Rotation.from_rotvec(x[:3]).as_matrix()
            D = np.eye(4)
            D[:3, :3] = dR
            D[:3, 3] = c + x[3:] - dR @ c  # the small rotation is about the moved model's centroid
            T = D @ T
            path.append(T.copy())
    return Refinement(T, np.asarray(path).reshape(-1, 4, 4), np.asarray(cost, np.float64))


def pose_quality(model: RegistrationModel, T: np.ndarray, camera: Camera, depth: np.ndarray, tol: float,
                 rgb: np.ndarray | None = None, photo_weight: float = 2.0) -> float:
    """The refinement's keep criterion, no ground truth: the free-space consistency
    (``depth._consistency``, 0-1) of ``model`` moved by ``T``, minus ``photo_weight`` x its mean
    colour error (0-1) on the observed surface when ``rgb`` and the model's colours are given."""
    cons, photo = _consistency(model.points, T, camera, depth, tol, model.colors, rgb)
    return cons - photo_weight * photo if rgb is not None and np.isfinite(photo) else cons


def refined_registration(reg, model: RegistrationModel, scene: np.ndarray, camera: Camera, depth: np.ndarray,
                         tol: float, *, iterations: int = 15, radius_start: float = 0.015, radius_end: float = 0.005,
                         rgb: np.ndarray | None = None, keep: tuple[float, float] | None = None):
    """``reg`` (a ``depth.Registration``) moved to its ``refine_registration`` pose, with its
    fitness, consistency, score and rmse measured again there (``register``'s definitions, on
    the same model points, within ``tol``) and the refinement's iterations appended to its
    path (its ``path_cost`` gets the truncated distance before each step); alternatives are
    dropped (the refined pose is the one to judge). ``reg`` itself when no step was taken.

    ``keep`` = (photo_weight, margin): ``reg`` itself too when the refined pose's
    ``pose_quality`` (with ``rgb``) is more than ``margin`` below ``reg``'s. Why: the
    objective's two point-to-plane terms can agree on a wrong pose when the stored cloud is
    partial or its normals leave a direction free (a can's axis tilts, a box's faces slide),
    and the free space and the colours the refinement does not use tell such a pose (measured
    on the tuning pairs 300-900: docs/update.md, "Session 7: refinement regressions")."""
    ref = refine_registration(model, scene, reg.T_world, camera, depth, iterations=iterations,
                              radius_start=radius_start, radius_end=radius_end)
    if not len(ref.path):
        return reg
    T = ref.T_world
    if keep is not None and pose_quality(model, T, camera, depth, tol, rgb, keep[0]) \
            < pose_quality(model, reg.T_world, camera, depth, tol, rgb, keep[0]) - keep[1]:
        return reg
    with _one_openmp_thread():
        dist = model.tree.query(np.ascontiguousarray((np.asarray(scene, np.float64) - T[:3, 3]) @ T[:3, :3]))[0]
    fitness = float((dist <= tol).mean())
    rmse = float(np.sqrt(np.mean(dist[dist <= tol] ** 2))) if np.any(dist <= tol) else float("inf")
    cons = _consistency(model.points, T, camera, depth, tol)[0]
    path = ref.path if reg.path is None else np.concatenate([reg.path, ref.path])
    cost = ref.cost if reg.path_cost is None else np.concatenate([reg.path_cost, ref.cost])
    return replace(reg, T_world=T, score=fitness * cons, fitness=fitness, consistency=cons, rmse=rmse, path=path,
                   path_cost=cost, alternatives=())


def half_turn_symmetric(model: RegistrationModel, S: np.ndarray, ratio: float = 1.0) -> bool:
    """Whether the motion ``S`` ((4, 4), model frame) maps the model's points onto themselves:
    their mean distance to the nearest unmoved point is at most ``ratio`` x the points' own mean
    nearest-neighbour spacing (the sampling floor)."""
    with _one_openmp_thread():
        spacing = float(model.tree.query(model.points, k=2)[0][:, 1].mean())
        moved = float(model.tree.query(model.points @ S[:3, :3].T + S[:3, 3])[0].mean())
    return moved <= ratio * spacing


def flip_check(reg, model: RegistrationModel, scene: np.ndarray, camera: Camera, depth: np.ndarray,
               rgb: np.ndarray, tol: float, *, score_margin: float = 0.05, photo_margin: float = 0.02,
               iterations: int = 15, radius_start: float = 0.015, radius_end: float = 0.005,
               symmetric: tuple[float, float] | None = (1.0, 0.05)):
    """The half-turn ambiguity of a registration, decided by colour: ``reg``'s pose turned by
    180 deg about each principal axis of the model (through its centroid), each refined
    (``refined_registration``); the one of least colour error (``depth._consistency``'s photo
    term: mean absolute difference, 0-1, between the model's stored colours on the observed
    surface and ``rgb``) replaces ``reg`` when its score (fitness x consistency) is within
    ``score_margin`` of ``reg``'s (the geometry cannot tell them apart) and its colour error is
    lower by more than ``photo_margin``. Returns (registration, whether it was replaced).

    Why: a box or a flat object is nearly the same shape turned by a half turn about an axis, and
    the registration picks between such poses by geometry (and then by the least rotation);
    a printed texture is not symmetric. Measured on the cached pairs (docs/update.md, "Session 7:
    rotation").

    ``symmetric`` = (ratio, photo margin): a half turn that maps the stored points onto
    themselves (``half_turn_symmetric`` with ratio) needs its colour error lower by the larger
    photo margin (None: ``photo_margin`` for all). Why: the geometry cannot improve by such a
    turn, only the texture's side can, and a small colour gain there is the turned partial
    cloud's different fit, not the print (easy_300: 0.035 lower for 0.3 -> 4.6 deg up to
    symmetry; the printed box of the tests: 0.129; docs/update.md, "Session 7: refinement
    regressions")."""
    if model.colors is None or rgb is None:
        return reg, False
    p0 = _consistency(model.points, reg.T_world, camera, depth, tol, model.colors, rgb)[1]
    if not np.isfinite(p0):
        return reg, False
    c = model.points.mean(axis=0)
    _, V = np.linalg.eigh(np.cov((model.points - c).T))
    best, best_p = reg, p0
    for axis in V.T:
        S = np.eye(4)
        S[:3, :3] = Rotation.from_rotvec(axis * np.pi).as_matrix()
        S[:3, 3] = c - S[:3, :3] @ c  # the half turn about the model's own axis, in its old pose
        margin = photo_margin
        if symmetric is not None and half_turn_symmetric(model, S, symmetric[0]):
            margin = max(photo_margin, symmetric[1])
        # the path so far is kept: the replay shows the ICP, its refinement, then the half turn's
        start = replace(reg, T_world=reg.T_world @ S, alternatives=())
        r = refined_registration(start, model, scene, camera, depth, tol, iterations=iterations,
                                 radius_start=radius_start, radius_end=radius_end)
        if r is start:
            continue
        p = _consistency(model.points, r.T_world, camera, depth, tol, model.colors, rgb)[1]
        if np.isfinite(p) and r.score >= reg.score - score_margin and p < p0 - margin and p < best_p:
            best, best_p = r, p
    return best, best is not reg

