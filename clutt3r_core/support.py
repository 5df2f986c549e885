"""Support (table / tray) marking over super-voxels, and the RANSAC plane fit it uses.

The rule is stated in :mod:`clutt3r_core.supervoxels`' module docstring (ours; findings
point 4); it lives here so that module stays about clustering (eq. 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clutt3r_core.graph_ops import concat_ranges, connected_components
from clutt3r_core.pointcloud import FusedCloud
from clutt3r_core.segmentation.grouping import spatial_similarity

if TYPE_CHECKING:
    from clutt3r_core.supervoxels import SuperVoxelConfig

__all__ = ["fit_plane_ransac", "plane_inliers", "ransac_hypothesis", "refine_plane", "SupportPlanes", "support_planes", "mark_support"]


def fit_plane_ransac(
    points: np.ndarray,
    distance: float,
    iterations: int = 500,
    seed: int = 0,
    max_eval: int = 4000,
    normals: np.ndarray | None = None,
    min_normal_dot: float = 0.0,
) -> tuple[np.ndarray, np.ndarray] | None:
    """Dominant plane of ``points`` (N, 3) by RANSAC, refined by least squares on its inliers.

    Hypotheses are scored on a random subset of at most ``max_eval`` points (all
    hypotheses at once, vectorised). With ``normals`` (N, 3), an inlier must also have
    |<normal, plane normal>| >= ``min_normal_dot``. Returns ([nx, ny, nz, d] with unit n
    and arbitrary sign, (N,) bool inliers) or None for fewer than 3 points.
    """
    pts = np.asarray(points, dtype=np.float64)
    nr = np.asarray(normals, dtype=np.float64) if normals is not None and min_normal_dot > 0 else None
    plane = ransac_hypothesis(pts, distance, iterations, seed, max_eval, nr, min_normal_dot)
    if plane is None:
        return None

    return refine_plane(pts, nr, plane, distance, min_normal_dot)


def _scatter_normal(q: np.ndarray) -> np.ndarray:
    """The unit normal of centred points ``q`` (P, 3): the eigenvector of the smallest eigenvalue
    of their 3x3 scatter (the last right singular vector of their SVD, without the (P, 3) U
    factor that made the SVD slow)."""
    return np.linalg.eigh(q.T @ q)[1][:, 0]


def refine_plane(pts: np.ndarray, normals: np.ndarray | None, plane: np.ndarray, distance: float,
                 min_normal_dot: float, normal_of=_scatter_normal) -> tuple[np.ndarray, np.ndarray]:
    """Two least-squares refinements of ``plane`` [n, d] over its inliers (``plane_inliers``) of
    ``pts`` (N, 3) float64: (plane, (N,) bool inliers of the result). ``normal_of``: centred
    inliers (P, 3) -> unit normal (the benchmark's naive baseline passes a full SVD)."""
    for _ in range(2):
        inl = plane_inliers(pts, normals, plane, distance, min_normal_dot)
        if inl.sum() < 3:
            break
        q = pts[inl]
        cen = q.mean(axis=0)
        q -= cen
        normal = normal_of(q)
        plane = np.append(normal, -normal @ cen)
    return plane, plane_inliers(pts, normals, plane, distance, min_normal_dot)


def plane_inliers(points: np.ndarray, normals: np.ndarray | None, plane: np.ndarray, distance: float,
                  min_normal_dot: float) -> np.ndarray:
    """(N,) bool: ``points`` (N, 3) within ``distance`` of ``plane`` [n, d] and, with ``normals``
    (N, 3), |<normal, n>| >= ``min_normal_dot``."""
    ok = np.abs(points @ plane[:3] + plane[3]) <= distance
    if normals is not None:
        ok &= np.abs(normals @ plane[:3]) >= min_normal_dot
    return ok


def ransac_hypothesis(pts: np.ndarray, distance: float, iterations: int, seed: int, max_eval: int,
                      normals: np.ndarray | None, min_normal_dot: float) -> np.ndarray | None:
    """The best of ``iterations`` three-point plane hypotheses over ``pts`` (N, 3) float64, scored
    on at most ``max_eval`` of them (``fit_plane_ransac`` before its refinement); None for fewer
    than 3 points or only degenerate triples. ``normals``: (N, 3) float64, or None (no normal test)."""
    n = pts.shape[0]
    if n < 3:
        return None
    use_n = normals is not None
    rng = np.random.default_rng(seed)
    sel = np.arange(n) if n <= max_eval else rng.choice(n, max_eval, replace=False)
    ev, evn = pts[sel], (normals[sel] if use_n else None)
    tri = rng.integers(0, n, size=(iterations, 3))
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    nrm = np.cross(b - a, c - a)
    norm = np.linalg.norm(nrm, axis=1)
    good = norm > 1e-12
    if not good.any():
        return None
    nrm = nrm[good] / norm[good, None]
    d = -np.einsum("ij,ij->i", nrm, a[good])
    # Score in chunks so that (hypotheses x points) stays small.
    # Scoring is the hot part: float32 and chunks of 100 hypotheses keep it to a few ms.
    ev32, nrm32, d32 = ev.astype(np.float32), nrm.astype(np.float32), d.astype(np.float32)
    evn32 = evn.astype(np.float32) if use_n else None
    scores = []
    for i in range(0, len(d), 100):
        ok = np.abs(ev32 @ nrm32[i : i + 100].T + d32[i : i + 100]) <= distance
        if use_n:
            ok &= np.abs(evn32 @ nrm32[i : i + 100].T) >= min_normal_dot
        scores.append(ok.sum(axis=0))
    best = int(np.argmax(np.concatenate(scores)))
    return np.append(nrm[best], d[best])


def _group_extent(values: np.ndarray, labels: np.ndarray, k: int) -> np.ndarray:
    """(K, D) max - min of ``values`` (N, D) per label (every label must occur)."""
    order = np.argsort(labels, kind="stable")
    v = values[order]
    starts = np.flatnonzero(np.r_[True, np.diff(labels[order]) != 0])
    return np.maximum.reduceat(v, starts, axis=0) - np.minimum.reduceat(v, starts, axis=0)


def _patch_extent(uvh: np.ndarray, comp: np.ndarray, members: np.ndarray) -> np.ndarray:
    """(N,) extent (largest bounding-box side) of the connected patch of each member voxel, 0 elsewhere."""
    out = np.zeros(len(comp))
    if members.any():
        c = comp[members]
        _, inv = np.unique(c, return_inverse=True)
        ext = _group_extent(uvh[members], inv, int(inv.max()) + 1).max(axis=1)
        out[members] = ext[inv]
    return out


@dataclass(frozen=True, eq=False)
class SupportPlanes:
    """The RANSAC part of support marking (rules 1-3 without the patch graph), which needs only the
    cloud: ``support_planes`` computes it while the super-voxel graph is built (ours, issue 13).

    Attributes:
        plane: [nx, ny, nz, d] float64, unit normal oriented towards the cameras; None when no
            support plane was found (then nothing is marked and the other fields are empty).
        uvh: (N, 3) float64 voxel coordinates in the plane frame (e1, e2 in the plane, height).
        ground: (N,) bool, rule 2 (below the plane, or on it and facing along its normal).
        inliers: per further plane of rule 3, in fit order, (M_i,) int64 voxel indices ascending.
    """

    plane: np.ndarray | None
    uvh: np.ndarray
    ground: np.ndarray
    inliers: tuple[np.ndarray, ...]


def support_planes(cloud: FusedCloud, cfg: SuperVoxelConfig) -> SupportPlanes:
    """Rules 1-3's plane fits (the module doc of ``clutt3r_core.supervoxels``): the support plane,
    the ground voxels and the inliers of every further plane, in the order ``mark_support`` used
    them. Which voxels a further plane may take depends only on earlier fits, never on the
    patches, so this is the same sequence of fits as one loop over both."""
    pts = cloud.points.astype(np.float64)
    nrm = cloud.normals.astype(np.float64)
    none = SupportPlanes(None, np.zeros((0, 3)), np.zeros(0, bool), ())
    fit = fit_plane_ransac(pts, cfg.plane_distance, cfg.plane_iterations, cfg.plane_seed)
    if fit is None or fit[1].mean() < cfg.plane_min_inliers:
        return none
    plane, _ = fit
    # Orient the normal towards the cameras (or, without camera centres, along the
    # fused normals, which fuse_views already orients towards the cameras).
    if cloud.camera_centres is not None and len(cloud.camera_centres):
        side = np.sum(cloud.camera_centres @ plane[:3] + plane[3])
    else:
        side = np.sum(nrm[np.abs(pts @ plane[:3] + plane[3]) <= cfg.plane_distance] @ plane[:3])
    if side < 0:
        plane = -plane
    h = pts @ plane[:3] + plane[3]
    # rule 2: below the support plane, or on it and facing along its normal. The normal
    # test keeps the lowest centimetre of objects that stand on the support (their sides
    # face sideways) and of thin objects lying on it (a hammer handle) out of the support.
    facing = np.abs(nrm @ plane[:3]) >= np.cos(np.deg2rad(cfg.patch_max_angle))
    ground = (h < -cfg.plane_distance) | ((h <= cfg.plane_distance) & facing)

    # Plane frame (e1, e2 in the plane, h along its normal) for extents.
    nz = plane[:3]
    e1 = np.cross(nz, [1.0, 0.0, 0.0] if abs(nz[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(nz, e1)
    uvh = np.column_stack([pts @ e1, pts @ e2, h])

    # Rule 3's fits: further planes on the voxels no earlier fit took
    min_dot = float(np.cos(np.deg2rad(cfg.patch_max_angle)))
    min_inl = max(cfg.patch_min_voxels, 3)
    free = ~ground
    inliers = []
    for it in range(cfg.max_planes):
        idx = np.flatnonzero(free)
        if len(idx) < min_inl:
            break
        fit = fit_plane_ransac(
            pts[idx], cfg.plane_distance, cfg.plane_iterations, cfg.plane_seed + 1 + it,
            normals=nrm[idx], min_normal_dot=min_dot,
        )
        if fit is None or fit[1].sum() < min_inl:
            break
        members = idx[fit[1]]
        free[members] = False  # never re-fit these voxels, large patch or not
        inliers.append(members)
    return SupportPlanes(plane, uvh, ground, tuple(inliers))


def mark_support(
    cloud: FusedCloud,
    labels: np.ndarray,
    k: int,
    counts: np.ndarray,
    src: np.ndarray,
    dst: np.ndarray,
    dist: np.ndarray,
    cfg: SuperVoxelConfig,
    planes: SupportPlanes | None = None,
) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
    """(support (K,) bool, plane or None, planar (K,) bool); the rule is in the module doc of
    ``clutt3r_core.supervoxels``. ``planes``: ``support_planes(cloud, cfg)`` when computed
    already (the super-voxel stage runs it beside its graph). ``planar``: the support
    super-voxels that only rule 3's large planar patches marked (without them, neither the ground
    fraction of rule 2 nor their own extent would). Ours (session 9): on hard scenes a can's top level with a tray rim, or
    the flat tops of touching objects, join one patch wider than any object."""
    if planes is None:
        planes = support_planes(cloud, cfg)
    if planes.plane is None:
        return np.zeros(k, bool), None, np.zeros(k, bool)
    n = cloud.num
    uvh = planes.uvh
    bad = planes.ground.copy()

    # Rule 3: further large planar patches (tray walls, rims, a raised tray floor).
    near = dist <= 2.0 * cloud.voxel_size  # patch connectivity: k-NN pairs within two voxels
    near_src, near_dst = src[near], dst[near]
    del near
    if len(near_src) > 1 and np.any(near_src[1:] < near_src[:-1]):  # the k-NN edges come sorted
        order = np.argsort(near_src, kind="stable")
        near_src, near_dst = near_src[order], near_dst[order]
    # edges out of voxel i: near_ptr[i]:near_ptr[i + 1] (a plane's patch graph gathers only
    # its members' edges: masking all 1.2 M edges per plane was a third of this function)
    near_ptr = np.zeros(n + 1, np.int64)
    np.cumsum(np.bincount(near_src, minlength=n), out=near_ptr[1:])
    slot = np.empty(n, np.int32)  # a voxel's index among the current plane's inliers
    for members in planes.inliers:
        inl = np.zeros(n, bool)
        inl[members] = True
        # patches: components of the inliers' own graph (a few thousand voxels, not all N)
        e = concat_ranges(near_ptr[members], near_ptr[members + 1])  # edges out of members, in order
        e = e[inl[near_dst[e]]]
        slot[members] = np.arange(len(members), dtype=np.int32)
        comp = np.zeros(n, np.int64)
        comp[members] = connected_components(len(members), slot[near_src[e]], slot[near_dst[e]])
        big = _patch_extent(uvh, comp, inl) >= cfg.max_object_extent
        bad |= big

    w = cloud.counts.astype(np.float64)
    frac = np.bincount(labels, weights=w * bad, minlength=k) / np.maximum(counts, 1)
    ext = _group_extent(uvh, labels, k).max(axis=1)
    support = (frac >= cfg.support_fraction) | (ext >= cfg.max_object_extent)
    ground = np.bincount(labels, weights=w * planes.ground, minlength=k) / np.maximum(counts, 1)
    planar = support & (ground < cfg.support_fraction) & (ext < cfg.max_object_extent)
    return support, planes.plane, planar


def planar_covered(planar: np.ndarray, occupancy: np.ndarray, mask_view: np.ndarray, object_mask: np.ndarray,
                   visible: np.ndarray, min_share: float, min_occupancy: float = 0.5) -> np.ndarray:
    """(K,) bool: the ``planar`` super-voxels that object masks cover in most views that see them
    (``SuperVoxelConfig.planar_mask_views``; ours, session 9).

    ``planar``: (K,) bool, support marked by rule 3 alone (``SuperVoxels.planar``); ``occupancy``:
    (M, K) float o_i(k) of every mask (Sec. III-B eq. 2, over k's points visible in the mask's
    view); ``mask_view``: (M,) int view of each mask, 0..V-1; ``object_mask``: (M,) bool, a mask
    that the other support rules do not make background; ``visible``: (V, K) bool, view v sees a
    point of k. A view covers k when one of its object masks has o_i(k) >= ``min_occupancy``;
    k is covered when at least 2 views and a fraction ``min_share`` of the views seeing it do.
    """
    planar = np.asarray(planar, bool)
    k = planar.shape[0]
    visible = np.asarray(visible, bool)
    if occupancy.shape[1:] != (k,) or visible.shape[1:] != (k,) or len(mask_view) != occupancy.shape[0]:
        raise ValueError(f"planar_covered: shapes {planar.shape}, {occupancy.shape}, {visible.shape}, {len(mask_view)}")
    out = np.zeros(k, bool)
    cols = np.flatnonzero(planar)
    if not len(cols) or min_share <= 0:
        return out
    rows = np.flatnonzero(np.asarray(object_mask, bool))
    covered = np.zeros((visible.shape[0], len(cols)), bool)
    if len(rows):
        hit = occupancy[np.ix_(rows, cols)] >= min_occupancy  # (R, C)
        np.logical_or.at(covered, np.asarray(mask_view)[rows], hit)
    covered &= visible[:, cols]
    n_cov = covered.sum(axis=0)
    n_vis = visible[:, cols].sum(axis=0)
    out[cols] = (n_cov >= 2) & (n_cov >= min_share * np.maximum(n_vis, 1))
    return out


def kept_spatial(occupancy: np.ndarray, weights: np.ndarray, support: np.ndarray, first_support: np.ndarray,
                 first_object: np.ndarray) -> np.ndarray:
    """(U, U) float32 S_spatial (eq. 2) over the super-voxels that are not ``support``, except
    between two ``first_object`` masks: theirs stays over the super-voxels that are not
    ``first_support`` (ours, session 10; ``SuperVoxelConfig.planar_mask_views``).

    ``occupancy``: (U, K) o_i(k); ``weights``: (K,) w_hat_k; ``support``: (K,) bool, the support
    after ``planar_covered`` un-marked part of ``first_support`` (K,) bool, the support the masks'
    first background flags were taken with (``support`` must be a subset of it); ``first_object``:
    (U,) bool, the masks that were not background under ``first_support`` (every mask when
    background masks are not excluded).

    The un-marking adds to the grouping: the masks it re-admits (a flat top's masks seen from
    above) link to every mask over the un-marked super-voxels, but the edges between the masks the
    default already grouped stay as the default computed them. With the un-marked columns in those
    edges too, an object's masks from above (which cover its top) and from the side (which do not)
    drift apart, and greedy stage 1 split a box with two masks in 5 of its 8 views into two
    instances (generated hard_0002; docs/benchmark/strict-iou.md, session 10).
    """
    occ = np.asarray(occupancy, np.float32)
    support = np.asarray(support, bool)
    first_support = np.asarray(first_support, bool)
    first_object = np.asarray(first_object, bool)
    u, k = occ.shape
    if support.shape != (k,) or first_support.shape != (k,) or first_object.shape != (u,) or len(weights) != k:
        raise ValueError(f"kept_spatial: shapes {occ.shape}, {np.shape(weights)}, {support.shape}, "
                         f"{first_support.shape}, {first_object.shape}")
    if (support & ~first_support).any():
        raise ValueError("kept_spatial: support must be a subset of first_support (the un-marking only removes)")
    s = spatial_similarity(np.where(support[None, :], 0.0, occ).astype(np.float32), weights)
    keep = np.flatnonzero(first_object)
    if (support != first_support).any() and len(keep):
        s[np.ix_(keep, keep)] = spatial_similarity(
            np.where(first_support[None, :], 0.0, occ[keep]).astype(np.float32), weights)
    return s
