"""Depth cues of the scene update (ours; used only when the post-interaction view has depth).

Issue 10 asks to "use the new depth when it exists". The paper's change test (projected IoU
< tau_IoU) and its silhouette/photometric pose fit work without depth; with depth, three
cheaper and sharper tests are available (measured reasons in docs/update.md):

1. **In place** (``place_check``): a stored point that the new camera should see (it wins the
   z-buffer of the present instances at its centre pixel) is compared with the new depth at
   that pixel: *agree* (|d - z| <= tol), *farther* (d > z + tol: the place is empty now, we see
   past it) or *nearer* (d < z - tol: something new is in front; says nothing). An instance
   is in place when agree / (agree + farther) >= ``in_place_fraction``. Per point, not per
   pixel: a splat's rim spills over the silhouette onto the background, so a per-pixel test
   finds 10-30 % "farther" pixels on static objects (measured, 4 hard pairs), while their
   points agree.
2. **Explained pixels** (``explained_pixels``): pixels whose new depth agrees with an in-place
   instance's projected depth. A mask candidate minus its explained pixels is what is new in
   it (a displaced object's mask merged with a static neighbour's keeps only the former).
3. **Registration** (``register``): the depth points of a mask (minus explained pixels) are
   aligned to the stored instance points with a multi-start trimmed point-to-point ICP (scene
   -> model: every observed point has a partner on the fuller stored cloud, not vice versa),
   started from yaws every 30 deg and from the six ways the object's up axis can point
   (a push can tip an object over: 4 of the 18 generated pairs tilt it by 25-160 deg), all
   hypotheses iterated together (batched Kabsch); after 5 iterations the 8 of lowest distance
   go on, plus ``keep_consistent`` of the rest with the best inlier fraction x free-space
   consistency (``_consistency_batch``: on a partial view many wrong poses are as close as the
   right one). Each result is scored both ways:
   ``fitness`` = fraction of the scene points within ``tol`` of the moved model, and
   ``consistency`` = of the moved model's points that the camera would see in front of the
   observed surface or on it, the fraction on it (a pose that puts model points where the
   camera sees through empty space is wrong: a free-space test, so a partial view does not
   fit any pose that covers it). Score = fitness x consistency; near-ties (within
   ``tie_margin``) go to the smallest rotation (symmetric objects look the same in many
   poses; the least motion is the natural choice). Each accepted registration is then refined
   by a symmetric point-to-plane ICP and checked against its half turns by colour
   (``depth_refine.py``, ``PoseConfig.registration_refine_iterations`` / ``registration_flip_check``).
4. **Unexplained regions** (``unexplained_regions``): the new depth pixels that nothing stored
   explains (no unmoved instance, no background point, no accepted fit agrees with them) and
   that stand above the support plane, grouped into connected regions (4-neighbours whose
   depths differ by less than a link distance). A displaced object whose mask the detector
   dropped or split is such a region: a registration target without a mask.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage
from scipy.spatial.transform import Rotation

from clutt3r_core.graph_ops import connected_components
from clutt3r_core.normals import _one_openmp_thread, estimate_normals, knn_tree
from clutt3r_core.scene import Camera
from clutt3r_core.update.project import splat

__all__ = ["PlaceCheck", "place_check", "explained_pixels", "mask_points", "Registration", "register", "model_subset",
           "start_rotations", "support_plane", "unexplained_regions"]


@dataclass(frozen=True, eq=False)
class PlaceCheck:
    """Per-instance comparison of the stored points with the new depth (module docstring, 1).

    Attributes:
        ids: (K,) int32 instances checked.
        agree, farther, nearer: (K,) int64 counts of visible stored points whose new depth is
            within tol / behind by more than tol / in front by more than tol.
    """

    ids: np.ndarray
    agree: np.ndarray
    farther: np.ndarray
    nearer: np.ndarray
    visible: np.ndarray | None = None
    """(K,) int64 visible stored points (with or without valid depth at their pixel)."""

    def fraction(self, i: int) -> float:
        """agree / (agree + farther) of row i (NaN when no point could be compared)."""
        n = self.agree[i] + self.farther[i]
        return float(self.agree[i] / n) if n else float("nan")

    def judged(self, i: int, min_points: int, min_valid: float = 0.5) -> bool:
        """At least ``min_points`` compared, and at least ``min_valid`` of the visible points
        have depth (an old place seen as a depth hole says nothing, however few points agree)."""
        n = int(self.agree[i] + self.farther[i])
        if n < min_points:
            return False
        if self.visible is None:
            return True
        return n + int(self.nearer[i]) >= min_valid * int(self.visible[i])


def _depth_at(depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
    H, W = depth.shape
    u = np.round(uv[:, 0])
    v = np.round(uv[:, 1])
    ok = np.isfinite(u) & np.isfinite(v) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
    d = np.full(len(uv), np.nan)
    d[ok] = depth[v[ok].astype(np.int64), u[ok].astype(np.int64)]
    d[~(d > 0)] = np.nan
    return d


def place_check(points: np.ndarray, instance: np.ndarray, ids: np.ndarray, camera: Camera, depth: np.ndarray,
                voxel: float, tol: float) -> PlaceCheck:
    """Compare the visible stored points of ``ids`` (z-buffered together) with ``depth`` (m)."""
    ids = np.asarray(ids, np.int32)
    sel = np.isin(instance, ids)
    pts, lab = points[sel], instance[sel]
    s = splat(pts, camera, voxel, with_points=False)
    K = len(ids)
    agree, farther, nearer, visible = (np.zeros(K, np.int64) for _ in range(4))
    if not (s.h and s.w):
        return PlaceCheck(ids, agree, farther, nearer, visible)
    vis = s.visible()
    uv, _ = camera.project(pts)
    d = _depth_at(depth, uv)
    ok = vis & np.isfinite(d)
    a = ok & (np.abs(d - s.z) <= tol)
    f = ok & (d > s.z + tol)
    n = ok & (d < s.z - tol)
    lut = {int(k): i for i, k in enumerate(ids)}
    li = np.array([lut[int(x)] for x in lab], np.int64) if len(lab) else np.zeros(0, np.int64)
    agree[:] = np.bincount(li[a], minlength=K)
    farther[:] = np.bincount(li[f], minlength=K)
    nearer[:] = np.bincount(li[n], minlength=K)
    visible[:] = np.bincount(li[vis], minlength=K)
    return PlaceCheck(ids, agree, farther, nearer, visible)


def explained_pixels(points: np.ndarray, instance: np.ndarray, ids: np.ndarray, camera: Camera,
                     depth: np.ndarray, voxel: float, tol: float) -> np.ndarray:
    """(H, W) bool: pixels where instances ``ids`` (z-buffered) project and the new depth agrees
    with their projected depth within ``tol`` (these pixels show those instances, unmoved)."""
    H, W = camera.height, camera.width
    out = np.zeros((H, W), bool)
    if not len(ids):
        return out
    s = splat(points[np.isin(instance, ids)], camera, voxel, with_points=False)
    if s.h and s.w:
        local = np.isfinite(s.zbuf) & (np.abs(s.crop(depth) - s.zbuf) <= tol)
        out[s.v0 : s.v0 + s.h, s.u0 : s.u0 + s.w] = local
    return out


def support_plane(background: np.ndarray, objects: np.ndarray, tol: float) -> np.ndarray | None:
    """[nx, ny, nz, d] of the dominant plane of the ``background`` points (N, 3) by RANSAC
    (``support.fit_plane_ransac``, inliers within ``tol`` / 2), oriented so that the median of
    ``objects`` (M, 3) is on its positive side; None with fewer than 100 background points."""
    from clutt3r_core.support import fit_plane_ransac

    if len(background) < 100:
        return None
    background = np.asarray(background, np.float64)
    if len(background) > 20000:  # the table is most of them: 20 k points place it as well, 5x cheaper
        background = background[np.random.default_rng(0).choice(len(background), 20000, replace=False)]
    fit = fit_plane_ransac(background, tol / 2)
    if fit is None:
        return None
    plane = np.asarray(fit[0], np.float64)
    if len(objects) and np.median(np.asarray(objects, np.float64) @ plane[:3] + plane[3]) < 0:
        plane = -plane
    return plane


def unexplained_regions(camera: Camera, depth: np.ndarray, explained: np.ndarray, plane: np.ndarray | None,
                        min_height: float, link: float, min_pixels: int) -> list[np.ndarray]:
    """(H, W) bool regions of valid, unexplained depth pixels (module docstring, 4), largest
    first: pixels whose world point lies more than ``min_height`` (m) above ``plane`` (all
    unexplained pixels without a plane), linked to their 4-neighbours when the depths differ
    by less than ``link`` (m); regions under ``min_pixels`` pixels are dropped."""
    valid = np.isfinite(depth) & (depth > 0) & ~explained
    if plane is not None and valid.any():
        vs, us = np.nonzero(valid)
        h = camera.pixels_to_world(us, vs, depth[vs, us]) @ plane[:3] + plane[3]
        valid[vs[h <= min_height], us[h <= min_height]] = False
    n = int(np.count_nonzero(valid))
    if n < max(min_pixels, 1):
        return []
    idx = np.full(depth.shape, -1, np.int64)
    idx[valid] = np.arange(n)
    d = np.where(valid, depth, 0.0)  # only pairs of valid pixels are linked
    src, dst = [], []
    for a, b in (((slice(None), slice(None, -1)), (slice(None), slice(1, None))),
                 ((slice(None, -1), slice(None)), (slice(1, None), slice(None)))):
        e = valid[a] & valid[b] & (np.abs(d[a] - d[b]) < link)
        src.append(idx[a][e])
        dst.append(idx[b][e])
    lab = connected_components(n, np.concatenate(src), np.concatenate(dst))
    sizes = np.bincount(lab)
    vs, us = np.nonzero(valid)  # row-major, the order of idx
    out = []
    for c in np.argsort(-sizes, kind="stable"):
        if sizes[c] < min_pixels:
            break
        m = np.zeros(depth.shape, bool)
        sel = lab == c
        m[vs[sel], us[sel]] = True
        out.append(m)
    return out


def mask_points(camera: Camera, depth: np.ndarray, mask: np.ndarray, exclude: np.ndarray | None = None,
                erode: int = 2, max_points: int = 400, seed: int = 0) -> np.ndarray:
    """(n, 3) world points of the mask's valid depth pixels (eroded by ``erode`` px against
    bleeding onto the background; minus ``exclude``), uniformly subsampled to ``max_points``."""
    m = ndimage.binary_erosion(mask, iterations=erode) if erode > 0 else mask.copy()
    if m.sum() < 20:
        m = mask.copy()
    if exclude is not None:
        m &= ~exclude
    vs, us = np.nonzero(m & np.isfinite(depth) & (depth > 0))
    if not len(us):
        return np.zeros((0, 3))
    if len(us) > max_points:
        idx = np.sort(np.random.default_rng(seed).choice(len(us), max_points, replace=False))
        us, vs = us[idx], vs[idx]
    return camera.pixels_to_world(us, vs, depth[vs, us])


def start_rotations(yaw_step_deg: float = 30.0, tilts: bool = True) -> np.ndarray:
    """(S, 3, 3) start rotations (about the object's centroid, world axes): yaws every
    ``yaw_step_deg`` after each of the six up-axis placements (identity, +-90 deg about x and y,
    180 deg about x) when ``tilts``, else after the identity only."""
    ups = [np.zeros(3)]
    if tilts:
        ups += [np.array(v) * np.pi / 2 for v in ((1, 0, 0), (-1, 0, 0), (0, 1, 0), (0, -1, 0))] + [np.array([np.pi, 0, 0])]
    yaws = np.deg2rad(np.arange(0.0, 360.0, yaw_step_deg))
    out = []
    for u in ups:
        Ru = Rotation.from_rotvec(u).as_matrix()
        for y in yaws:
            out.append(Rotation.from_rotvec([0, 0, y]).as_matrix() @ Ru)
    return np.stack(out)


@dataclass(frozen=True, eq=False)
class Registration:
    """The best alignment of one instance to one mask's depth points.

    Attributes:
        T_world: (4, 4) motion of the stored points, ``p_new = T_world @ p_old``.
        score: fitness x consistency in [0, 1].
        fitness: fraction of the scene points within tol of the moved model.
        consistency: of the moved model points seen on or in front of the observed surface,
            the fraction on it.
        rmse: metres, RMS distance of the scene points to the moved model (inliers).
        n_scene: scene points used.
    """

    T_world: np.ndarray
    score: float
    fitness: float
    consistency: float
    rmse: float
    n_scene: int
    path: np.ndarray | None = None
    """(I, 4, 4) the motion after each ICP iteration of the chosen start (the last = T_world)."""
    path_cost: np.ndarray | None = None
    """(I,) metres: mean distance of the scene points to the moved model, truncated at the
    iteration's correspondence radius, after each iteration."""
    alternatives: tuple = ()
    """The next-best distinct poses (``register(alternatives=...)``), best rank first, each a
    ``Registration`` (without alternatives of its own): the acceptance tests after the
    registration (IoU) may reject this pose and pass one of them (ChangeConfig.registration_alternatives)."""


def _kabsch_batch(A: np.ndarray, B: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted rigid (R, t) with R A + t ~ B, batched: A, B (S, n, 3), w (S, n) -> (S,3,3), (S,3)."""
    ws = np.maximum(w.sum(axis=1, keepdims=True), 1e-9)
    # matmul, not einsum / broadcast sums: ~10x less CPU on (72, 250, 3), the same sums up to
    # their rounding order (~1e-14)
    ca = np.matmul(w[:, None], A)[:, 0] / ws
    cb = np.matmul(w[:, None], B)[:, 0] / ws
    H = np.matmul(((A - ca[:, None]) * w[..., None]).transpose(0, 2, 1), B - cb[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("sij,sjk->sik", Vt.transpose(0, 2, 1), U.transpose(0, 2, 1))))
    D = np.tile(np.eye(3), (len(A), 1, 1))
    D[:, 2, 2] = d
    R = np.einsum("sij,sjk,skl->sil", Vt.transpose(0, 2, 1), D, U.transpose(0, 2, 1))
    t = cb - np.einsum("sij,sj->si", R, ca)
    return R, t


def _point_to_plane_batch(A: np.ndarray, B: np.ndarray, N: np.ndarray, w: np.ndarray):
    """One linearised point-to-plane step, batched: min sum w ((dR A + dt - B) . N)^2 over a small
    rotation vector and a translation; (S, n, 3) inputs -> (S, 3, 3), (S, 3)."""
    J = np.concatenate([np.cross(A, N), N], axis=2)  # (S, n, 6)
    r = ((B - A) * N).sum(axis=2)
    Jw = J * w[..., None]
    # matmul, not a three-operand einsum: ~10x less CPU, the same sums up to rounding order
    H = np.matmul(Jw.transpose(0, 2, 1), J) + 1e-6 * np.eye(6)
    g = np.matmul(Jw.transpose(0, 2, 1), r[..., None])[..., 0]
    x = np.linalg.solve(H, g[..., None])[..., 0]
    dR = Rotation.from_rotvec(x[:, :3]).as_matrix()
    # the linearisation is about the origin: A' = dR A + dt with dt = x[3:]
    return dR, x[:, 3:]


def _on_or_in_front(p: np.ndarray, camera: Camera, depth: np.ndarray, tol: float):
    """The free-space test's per-point parts for moved model points ``p`` (..., 3) metres, world:
    (uv (..., 2) pixels, on (...) bool: within ``tol`` of the observed depth, front (...) bool:
    more than ``tol`` in front of it); points behind the camera or without depth are neither."""
    uv, z = camera.project(p.reshape(-1, 3))
    d = _depth_at(depth, uv)
    ok = np.isfinite(d) & (z > 0)
    on = ok & (np.abs(d - z) <= tol)
    front = ok & (z < d - tol)
    return uv, on.reshape(p.shape[:-1]), front.reshape(p.shape[:-1])


def _consistency(model: np.ndarray, T: np.ndarray, camera: Camera, depth: np.ndarray, tol: float,
                 colors: np.ndarray | None = None, rgb: np.ndarray | None = None) -> tuple[float, float]:
    """(consistency, photo): the free-space test of the module docstring, and the mean absolute
    colour difference (0-1) between the stored colours of the model points on the observed
    surface and the image there (NaN without colours)."""
    uv, on, front = _on_or_in_front(model @ T[:3, :3].T + T[:3, 3], camera, depth, tol)
    n = int(on.sum() + front.sum())
    photo = float("nan")
    if colors is not None and rgb is not None and on.any():
        u = np.round(uv[on, 0]).astype(np.int64)
        v = np.round(uv[on, 1]).astype(np.int64)
        photo = float(np.abs(rgb[v, u].astype(np.float64) - colors[on].astype(np.float64)).mean() / 255.0)
    return (float(on.sum() / n) if n else 0.0), photo


def _consistency_batch(model: np.ndarray, R: np.ndarray, t: np.ndarray, camera: Camera, depth: np.ndarray,
                       tol: float) -> np.ndarray:
    """(S,) the free-space consistency (``_consistency``) of ``model`` moved by each (R[s], t[s])."""
    _, on, front = _on_or_in_front(np.einsum("sij,nj->sni", R, model) + t[:, None], camera, depth, tol)
    on, front = on.sum(axis=1), front.sum(axis=1)
    n = on + front
    return np.where(n > 0, on / np.maximum(n, 1), 0.0)


@dataclass(frozen=True, eq=False)
class RegistrationModel:
    """An instance's stored points made ready for ``register`` once, for all its targets.

    Attributes:
        points: (M, 3) float64 metres, world (old pose): at most ``max_model_points`` of the
            instance's points (a seeded random subset, in their order).
        colors: (M, 3) uint8 their colours, or None.
        tree: k-d tree over ``points`` (``normals.knn_tree``).
        normals: (M, 3) unit PCA normals of ``points`` (10 nearest).
    """

    points: np.ndarray
    colors: np.ndarray | None
    tree: object
    normals: np.ndarray

    def __post_init__(self):
        if self.points.ndim != 2 or self.points.shape[1] != 3 or self.normals.shape != self.points.shape:
            raise ValueError(f"RegistrationModel: points {self.points.shape} and normals {self.normals.shape} "
                             "must both be (M, 3)")


def model_subset(n: int, max_model_points: int = 1500, seed: int = 0) -> np.ndarray | None:
    """Sorted indices of the stored points a registration uses (``prepare_model``), None when all
    ``n`` are used: the same draw wherever the model's points are needed without its normals."""
    if n <= max_model_points:
        return None
    return np.sort(np.random.default_rng(seed).choice(n, max_model_points, replace=False))


def prepare_model(model: np.ndarray, colors: np.ndarray | None = None, max_model_points: int = 1500,
                  seed: int = 0) -> RegistrationModel:
    """``register``'s per-instance work (subset, k-d tree, normals), done once: registering one
    instance to several targets with it gives the same results as passing the points each time."""
    model = np.asarray(model, np.float64)
    keep_idx = model_subset(len(model), max_model_points, seed)
    if keep_idx is not None:
        model = model[keep_idx]
        colors = None if colors is None else np.asarray(colors)[keep_idx]
    model = np.ascontiguousarray(model)
    # the fusion's PCA normals, 10 nearest (fewer than 20 points are never registered)
    normals = estimate_normals(model, 10) if len(model) >= 20 else np.zeros_like(model)
    # pykdtree on one thread (as the normals): the same neighbours and float64 distances as
    # scipy's cKDTree here, at 0.64x its query CPU (72 starts x 250 scene points on a 507-point
    # model; the queries are ~65 % of a registration; docs/update.md, session 6 second pass)
    return RegistrationModel(model, colors, knn_tree(model), normals)


def register(model: np.ndarray | RegistrationModel, scene: np.ndarray, camera: Camera, depth: np.ndarray, *,
             starts: np.ndarray, iterations: int = 12, keep: int = 8, prune_at: int = 4, tol: float = 0.01,
             keep_consistent: int = 0,
             max_model_points: int = 1500, tie_margin: float = 0.03, seed: int = 0,
             colors: np.ndarray | None = None, rgb: np.ndarray | None = None,
             photo_weight: float = 0.0, alternatives: int = 0) -> Registration | None:
    """Align ``model`` (stored points, old world pose) to ``scene`` (new depth points of a mask)
    from every start rotation (module docstring, 3). None when there are too few scene points.
    ``alternatives``: also return up to this many next-best poses by rank (fitness x consistency,
    minus the colour term), skipping any within 2 deg and 5 mm of a pose returned before them
    (starts that converged to one pose), in ``Registration.alternatives``. ``model`` may be a
    ``prepare_model`` result (then ``colors``, ``max_model_points`` and ``seed`` are its own)."""
    if len(scene) < 20 or len(model if not isinstance(model, RegistrationModel) else model.points) < 20:
        return None
    if not isinstance(model, RegistrationModel):
        model = prepare_model(model, colors, max_model_points, seed)
    tree, normals, colors = model.tree, model.normals, model.colors
    model = model.points
    if not photo_weight:  # no colour tie-break: the candidates' colour error would go unused
        colors = None
    cm, cs = model.mean(axis=0), scene.mean(axis=0)
    with _one_openmp_thread():
        return _icp(model, scene, camera, depth, tree, normals, cm, cs, colors, rgb, starts=starts,
                    iterations=iterations, keep=keep, prune_at=prune_at, tol=tol, keep_consistent=keep_consistent,
                    tie_margin=tie_margin, photo_weight=photo_weight, alternatives=alternatives)


def _icp(model, scene, camera, depth, tree, normals, cm, cs, colors, rgb, *, starts, iterations, keep, prune_at, tol,
         keep_consistent, tie_margin, photo_weight, alternatives) -> Registration:
    """``register``'s ICP from every start, prune, and pick (its arguments, the model's k-d tree
    and normals, the model and scene centroids)."""
    # G maps scene -> model frame: G s = R (s - cs) + cm + t; the start rotation R = S^T
    # (the model turned by S matches the scene, so the scene turned back by S^T matches the model)
    R = np.ascontiguousarray(starts.transpose(0, 2, 1))
    t = np.zeros((len(R), 3))
    src = scene - cs
    # correspondences beyond this are not trusted: shrinks from 3 cm to tol over the iterations
    hist: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []  # (R, t, cost) per iteration
    for it in range(iterations):
        max_d = max(tol * 1.5, 0.03 * (1 - it / max(iterations - 1, 1)) + tol * 1.5 * it / max(iterations - 1, 1))
        A = np.matmul(src, R.transpose(0, 2, 1)) + cm + t[:, None]
        dist, j = tree.query(A.reshape(-1, 3), distance_upper_bound=max_d)
        dist = dist.reshape(len(R), -1)
        j = np.minimum(j.reshape(len(R), -1), len(model) - 1)
        w = np.isfinite(dist).astype(np.float64)
        B = model[j]
        if it <= prune_at:  # point-to-point while the starts are far off (robust) ...
            dR, dt = _kabsch_batch(A, B, w)
        else:  # ... then point-to-plane (converges along flat faces, where point-to-point slides)
            dR, dt = _point_to_plane_batch(A, B, normals[j], w)
        R = np.einsum("sij,sjk->sik", dR, R)
        t = np.einsum("sij,sj->si", dR, cm + t) + dt - cm
        # truncated mean distance: the inlier fraction saturates at 1 for partial views
        cost = np.minimum(dist, max_d).mean(axis=1)  # misses are inf
        hist.append((R, t, cost))
        if it == prune_at and len(R) > keep:  # keep the best starts only
            best = np.argsort(cost, kind="stable")[:keep]
            if keep_consistent:
                # model -> world motion of each hypothesis: T = G^-1, G s = R (s - cs) + cm + t
                Rw = R.transpose(0, 2, 1)
                tw = cs - np.einsum("sij,sj->si", Rw, cm + t)
                inl = (dist <= max_d).mean(axis=1)
                # a ranking, not the final test: every k-th model point (<= 600) ranks as well, ~2x cheaper
                # (<= 300 points lost easy_503's true start to its 180 deg flip)
                cons = _consistency_batch(model[:: -(-len(model) // 600)], Rw, tw, camera, depth, tol)
                kept = set(best.tolist())
                extra = [i for i in np.argsort(-(inl * cons), kind="stable") if i not in kept][:keep_consistent]
                best = np.concatenate([best, np.asarray(extra, np.int64)])
            R, t = R[best], t[best]
            hist = [(a[best], b[best], c[best]) for a, b, c in hist]
    A = np.matmul(src, R.transpose(0, 2, 1)) + cm + t[:, None]
    dist = tree.query(A.reshape(-1, 3))[0].reshape(len(R), -1)
    fitness = (dist <= tol).mean(axis=1)
    rmse = np.sqrt(np.array([np.mean(d[d <= tol] ** 2) if np.any(d <= tol) else np.inf for d in dist]))
    cands = []
    for s in range(len(R)):
        G = np.eye(4)
        G[:3, :3] = R[s]
        G[:3, 3] = cm + t[s] - R[s] @ cs
        T = np.linalg.inv(G)
        cons, photo = _consistency(model, T, camera, depth, tol, colors, rgb)
        ang = float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1))))
        rank = float(fitness[s]) * cons - (photo_weight * photo if np.isfinite(photo) else 0.0)
        cands.append((rank, ang, s, T, cons, float(fitness[s]) * cons))
    top = max(c[0] for c in cands)
    pick = min((c for c in cands if c[0] >= top - tie_margin), key=lambda c: c[1])

    def result(c, alt: tuple = ()) -> Registration:
        _, _, s, T, cons, score = c
        G = np.tile(np.eye(4), (len(hist), 1, 1))
        G[:, :3, :3] = [a[s] for a, _, _ in hist]
        G[:, :3, 3] = [cm + b[s] - a[s] @ cs for a, b, _ in hist]
        path = np.linalg.inv(G)  # model -> world motion after each iteration (batched inverse)
        path[-1] = T
        return Registration(T, score, float(fitness[s]), cons, float(rmse[s]), len(scene), path,
                            np.array([c[s] for _, _, c in hist]), alt)

    alt: list = []
    if alternatives:
        chosen = [pick]
        for c in sorted(cands, key=lambda c: (-c[0], c[2])):  # best rank first, ties by start
            if len(chosen) > alternatives:
                break
            if any(_same_pose(c[3], o[3], cm) for o in chosen):
                continue
            chosen.append(c)
        alt = [result(c) for c in chosen[1:]]
    return result(pick, tuple(alt))


def _same_pose(Ta: np.ndarray, Tb: np.ndarray, centre: np.ndarray, deg: float = 2.0, metres: float = 0.005) -> bool:
    """Whether two motions differ by less than ``deg`` in rotation and move ``centre`` (the
    model's centroid, world) to places less than ``metres`` apart."""
    cos = (np.trace(Ta[:3, :3].T @ Tb[:3, :3]) - 1) / 2
    ca, cb = Ta[:3, :3] @ centre + Ta[:3, 3], Tb[:3, :3] @ centre + Tb[:3, 3]
    return bool(np.degrees(np.arccos(np.clip(cos, -1, 1))) < deg and np.linalg.norm(ca - cb) < metres)
