"""Super-voxels: geometrically homogeneous clusters of voxels (Sec. III-A, eq. 1), plus support marking.

Super-voxels are the connected components of a k-NN graph over the voxels of a
``FusedCloud`` whose edges are the neighbour pairs with

    d_ij = alpha * ||x_i - x_j|| + beta * (1 - <n_i, n_j>) <= tau_merge        (eq. 1)

(Sec. IV: alpha = 0.5 per metre, beta = 1, tau_merge = 0.01). With these values an
edge needs ||x_i - x_j|| <= 2 cm and, between adjacent 5 mm voxels, normals within
about 7 degrees, so smooth surfaces chain together and creases cut them.

Support marking (ours; findings point 4). Background is more than "the largest
super-voxel": a tray floor, each tray wall and the table around a tray are separate
large super-voxels, and a few mask pixels bleeding onto one hand it to an object.
Super-voxels of the support are therefore *marked* (never deleted, the viewer shows
them) so that grouping and voting can ignore them. The rule, in order:

1. Fit the dominant plane by RANSAC over the voxel centres (our own seeded numpy
   RANSAC, so results are deterministic) and refine it by least squares over its
   inliers; orient its normal towards the cameras. In a tabletop scene the dominant
   plane is the table or the tray floor: both are larger than any object.
2. A voxel is *ground* when it lies on the plane (|signed distance| <= plane_distance)
   or below it (signed distance < -plane_distance): objects rest on the support, so
   nothing below it is an object (the table around a raised tray floor, table edges).
3. Further planes are fitted by sequential RANSAC on the remaining voxels (inliers
   also need a normal within patch_max_angle of the plane's). A voxel is *large-planar*
   when it belongs to a connected patch of inliers (k-NN pairs within two voxels)
   whose extent (largest side of its bounding box in the support-plane frame) is
   >= max_object_extent. Tray walls, rims and raised floors are such patches, even
   where depth noise breaks them into many small super-voxels; an object face is not,
   since no graspable tabletop object is that large.
4. A super-voxel is support when the point-count-weighted fraction of its voxels that
   are ground or large-planar is >= support_fraction, or when its own extent is
   >= max_object_extent.

A convex-hull rule ("objects project inside the floor") was tried first and dropped:
on sample_seq4 the RANSAC plane is the table around the tray, whose hull covers the
whole tray, so it marked nothing.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.normals import knn_query, knn_tree
from clutt3r_core.pointcloud import FusedCloud
from clutt3r_core.graph_ops import connected_components
from clutt3r_core.support import fit_plane_ransac, mark_support, support_planes

__all__ = ["SuperVoxelConfig", "SuperVoxels", "build_supervoxels", "fit_plane_ransac"]


@dataclass(frozen=True)
class SuperVoxelConfig:
    """Super-voxel construction (Sec. III-A eq. 1, Sec. IV) and support marking (ours)."""

    alpha: float = 0.5
    """Weight of the Euclidean distance in d_ij, per metre (Sec. IV, alpha = 0.5)."""

    beta: float = 1.0
    """Weight of the normal term (1 - <n_i, n_j>) in d_ij (Sec. IV, beta = 1.0)."""

    tau_merge: float = 0.01
    """Neighbours with d_ij <= tau_merge are contracted into one super-voxel (Sec. IV)."""

    knn: int = 10
    """Neighbours per voxel in the k-NN graph (ours: on a surface sampled at 5 mm the 8
    voxels of the surrounding ring plus a little slack for noisy, doubled surfaces;
    neighbours farther than tau_merge / alpha can never merge and are not queried)."""

    absolute_normal_dot: bool = True
    """Use |<n_i, n_j>| in eq. 1 (findings point 5: PCA normals have no reliable sign;
    the signed dot cost 4-11 AP even though fuse_views orients normals to the cameras)."""

    support_removal: bool = True
    """Mark support super-voxels (table, tray floor, walls, rims; see the module doc).
    False: ``support`` is all False and ``plane`` is None (paper-literal)."""

    plane_distance: float = 0.01
    """RANSAC inlier threshold and "on the plane" band, metres (ours: two 5 mm voxels,
    the depth noise of a RealSense-class sensor at 0.5-1 m)."""

    plane_iterations: int = 500
    """RANSAC hypotheses (ours; the support holds well over 30% of the voxels, so 500
    triplets miss it with probability below 1e-5)."""

    plane_seed: int = 0
    """Seed of the RANSAC sampler (ours: deterministic output)."""

    plane_min_inliers: float = 0.1
    """Minimum fraction of voxels on the plane for it to count as the support; below
    this no plane is reported and nothing is marked (ours)."""

    max_planes: int = 6
    """Further planes fitted after the support plane, rule 3 (ours: a tray has a floor,
    four walls and a rim; fitting stops early when no plane has patch_min_voxels)."""

    patch_min_voxels: int = 500
    """Fewest inliers for a further plane (ours: 500 voxels = 125 cm^2 at 5 mm)."""

    patch_max_angle: float = 30.0
    """Largest angle between a voxel's normal and a further plane's normal for the voxel
    to be an inlier, degrees (ours: rejects curved objects crossing the plane)."""

    support_fraction: float = 0.5
    """Point-weighted fraction of ground-or-outside voxels that makes a super-voxel
    support (ours: majority)."""

    planar_mask_views: float = 0.5
    """Un-mark a super-voxel that only rule 3 (a large planar patch) marked as support when
    object masks cover it in at least this fraction of the views that see it (a mask not
    background by the other rules covers >= half of its visible points), and in >= 2 views;
    0 = off (the paper preset: it has no support rules). Ours, session 9: on hard seeds 14-17,
    2 of 3 objects lost to the support were a can's top level with a tray rim and a hammer's top
    joined to its touching neighbours' in one patch wider than max_object_extent; ``pipeline``
    applies it once the masks are read. The masks it re-admits get leaf edges over the un-marked
    super-voxels; the edges between masks the other rules already admitted stay as without it
    (``support.kept_spatial``, session 10: with the un-marked columns in them, a box's top and
    side masks split into two instances). Measured at 0.5 (docs/benchmark/strict-iou.md, session
    10; RealSense-like depth, one process): tuning seeds 2-3 mean AP 53.50 -> 53.88 (AP25 / AP50
    equal), check seeds 0-1 identical, fresh hard 14-17 43.4 -> 45.2 (AP50 85.4 -> 88.7), hard
    10-13 50.4 -> 51.0; clean depth and the real samples' leaf-pair F1 unchanged; sample_seq1: one
    super-voxel of 3 points un-marked and labelled, which moves the seq1 update's fingerprints
    (4b8c0a9c76f2 / e9886116a89c -> e9c0c297afff / 43dfa2ea23ab: instance 2's frame-8 pose 13 mm /
    1.4 deg, statuses equal). The lead's held-out seeds 6-9 and 18-21 (24 scenes): easy AP 59.3 ->
    61.7, hard AP50 83.5 -> 86.0, intermediate equal, no scene lower."""

    max_object_extent: float = 0.3
    """A super-voxel whose bounding box (in the plane frame) has a side this long,
    metres, is support whatever its position (ours: larger than nearly every graspable tabletop
    object; four of the 78 YCB objects are longer, 048_hammer 0.333 m the longest, and a hammer
    lying in a tray lost 61 % of its points to this rule on a held-out scene; a geometric
    exception for long objects un-marked table super-voxels instead: docs/benchmark/strict-iou.md,
    "Session 10: long objects")."""

    def __post_init__(self) -> None:
        if self.alpha < 0 or self.beta < 0 or (self.alpha == 0 and self.beta == 0):
            raise SceneError(f"SuperVoxelConfig needs alpha, beta >= 0, not both 0; got {self.alpha}, {self.beta}")
        if not self.tau_merge > 0:
            raise SceneError(f"SuperVoxelConfig.tau_merge must be > 0, got {self.tau_merge}")
        if self.knn < 1:
            raise SceneError(f"SuperVoxelConfig.knn must be >= 1, got {self.knn}")
        if not self.plane_distance > 0:
            raise SceneError(f"SuperVoxelConfig.plane_distance must be > 0, got {self.plane_distance}")
        if not 0 < self.support_fraction <= 1:
            raise SceneError(f"SuperVoxelConfig.support_fraction must be in (0, 1], got {self.support_fraction}")
        if not 0 <= self.planar_mask_views <= 1:
            raise SceneError(f"SuperVoxelConfig.planar_mask_views must be in [0, 1], got {self.planar_mask_views}")


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class SuperVoxels:
    """Super-voxels of a fused cloud.

    Attributes:
        labels: (N,) int32 super-voxel of each voxel, 0..K-1.
        counts: (K,) int64 raw points per super-voxel (sum of its voxels' counts).
        weights: (K,) float64 normalised weight w_hat_k proportional to counts, sum 1 (eq. 2).
        support: (K,) bool, super-voxel is (part of) the support: table, tray floor,
            tray walls and rims (see the module doc). Grouping and voting ignore these.
        plane: (4,) float64 [nx, ny, nz, d] of the dominant plane, n . x + d = 0 with
            unit n pointing towards the cameras, or None when none was found / asked for.
        sizes: (K,) int64 number of voxels per super-voxel (ours).
        planar: (K,) bool, support marked by rule 3's large planar patches alone (ours, session 9;
            ``support.mark_support``), or None when not computed.
    """

    labels: np.ndarray
    counts: np.ndarray
    weights: np.ndarray
    support: np.ndarray
    plane: np.ndarray | None = None
    sizes: np.ndarray | None = None
    planar: np.ndarray | None = None

    def __post_init__(self) -> None:
        lab = np.asarray(self.labels, dtype=np.int32).reshape(-1)
        cnt = np.asarray(self.counts, dtype=np.int64).reshape(-1)
        k = cnt.shape[0]
        if lab.size and (lab.min() < 0 or lab.max() >= k):
            raise SceneError(f"SuperVoxels.labels must lie in 0..{k - 1}")
        w = np.asarray(self.weights, dtype=np.float64).reshape(-1)
        sup = np.asarray(self.support, dtype=bool).reshape(-1)
        if w.shape != (k,) or sup.shape != (k,):
            raise SceneError(f"SuperVoxels: counts, weights and support must all be ({k},)")
        sizes = np.bincount(lab, minlength=k) if self.sizes is None else np.asarray(self.sizes, np.int64)
        if sizes.shape != (k,):
            raise SceneError(f"SuperVoxels.sizes must be ({k},), got {sizes.shape}")
        object.__setattr__(self, "labels", _readonly(lab))
        object.__setattr__(self, "counts", _readonly(cnt))
        object.__setattr__(self, "weights", _readonly(w))
        object.__setattr__(self, "support", _readonly(sup))
        object.__setattr__(self, "sizes", _readonly(sizes.astype(np.int64)))
        if self.plane is not None:
            pl = np.asarray(self.plane, dtype=np.float64).reshape(-1)
            if pl.shape != (4,):
                raise SceneError(f"SuperVoxels.plane must be (4,), got {pl.shape}")
            object.__setattr__(self, "plane", _readonly(pl))
        if self.planar is not None:
            pb = np.asarray(self.planar, dtype=bool).reshape(-1)
            if pb.shape != (k,):
                raise SceneError(f"SuperVoxels.planar must be ({k},), got {pb.shape}")
            object.__setattr__(self, "planar", _readonly(pb & sup))

    @property
    def num(self) -> int:
        """Number of super-voxels K."""
        return int(self.counts.shape[0])

    def voxel_support(self) -> np.ndarray:
        """(N,) bool: the voxel belongs to a support super-voxel."""
        return self.support[self.labels]


def _knn_edges(
    points: np.ndarray, k: int, max_dist: float, neighbours: np.ndarray | None = None, make_tree=None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Directed k-NN pairs (i, j int32, ||x_i - x_j|| float64) with distance < max_dist, self
    excluded: the pairs of a k-NN query of k + 1 points bounded by max_dist (strictly, as
    scipy's cKDTree bounds it), by ``normals.knn_tree`` / ``knn_query`` (pykdtree, issue 13).

    ``neighbours``: the cloud's (N, k') nearest-first neighbour table (``FusedCloud.neighbours``,
    from the normals; issue 13: this second k-NN query was a quarter of the stage). Its
    distances are computed the way the k-d trees compute them, ((dx^2 + dy^2) + dz^2) in float64
    against the squared bound, then the square root: the same bits. A row's first k + 1
    entries are the query's neighbours when they are strictly nearer than the rest of the
    row and than any point outside it. The table was ranked on the float64 voxel means, not
    on these float32 points, so both comparisons allow for that rounding (``_ROUNDING_MARGIN``)
    and need only the (k+2)-th and the last entry of the row. Other rows (ties at the cut:
    voxel means on a millimetre depth grid, about 40 of 150 k voxels of sample_seq4) are
    queried as before. The pairs are then those of the query, up to their order within a
    row (tests/core/test_supervoxels.py). ``make_tree``: a callable giving ``knn_tree(points)``
    (built beside, by the caller), or None to build it here when a query needs it.
    """
    n = points.shape[0]
    kq = min(k + 1, n)
    pts = np.ascontiguousarray(points, np.float64)
    make_tree = make_tree or (lambda: knn_tree(pts))
    bound = max_dist * max_dist
    kt = 0 if neighbours is None or neighbours.shape[0] != n else neighbours.shape[1]
    if not (n and (kt > kq or kt == n >= kq)):  # no table, or too short a row to tell
        if not n:
            return np.zeros(0, np.int32), np.zeros(0, np.int32), np.zeros(0)
        rows = np.arange(n, dtype=np.int32)
        idx = _nearest(make_tree(), pts, pts, rows, kq, bound)
        return _pairs(rows, idx, np.sqrt(_sq_dist(pts, rows, idx)), n)
    # the k + 1 candidates, then (when the row has more) the next one and the farthest one
    cols = list(range(kq)) + ([kq, kt - 1] if kt > kq else [])
    margin = _ROUNDING_MARGIN * float(np.spacing(np.float32(np.abs(pts).max())))
    cols3 = [np.ascontiguousarray(pts[:, a]) for a in range(3)]
    tree = None
    # the pairs are written in place (at most kq per row): concatenating per-block parts
    # held the edges twice, the stage's peak at 1080p
    out_src = np.empty(n * kq, np.int32)
    out_dst = np.empty(n * kq, np.int32)
    out_dist = np.empty(n * kq)
    m = 0
    # blocks of rows: the (rows, k) temporaries stay a few MiB (issue 13, 1080p memory)
    for s in range(0, n, _EDGE_BLOCK):
        rows = np.arange(s, min(s + _EDGE_BLOCK, n), dtype=np.int32)
        idx = neighbours[s : s + len(rows)][:, cols]
        d2 = _sq_dist(cols3, rows, idx)
        d = np.sqrt(d2)
        if kt == kq:  # == n: every point is a neighbour, there is no cut
            exact = np.ones(len(rows), bool)
        else:
            inner = d[:, :kq].max(axis=1)
            # the rest of the row is at least the next entry's distance, and every point
            # outside the row (if any) at least the last entry's, each less the rounding margin
            rest = (d[:, kq] if kt == n else np.minimum(d[:, kq], d[:, kq + 1])) - margin
            exact = (inner < rest) | (rest >= max_dist)  # or the rest is beyond the bound anyway
        idx, dist = idx[:, :kq].astype(np.int64), d[:, :kq]
        idx[d2[:, :kq] >= bound] = n  # beyond the bound: "no neighbour", as the query reports it
        redo = np.flatnonzero(~exact)
        if len(redo):
            tree = make_tree() if tree is None else tree
            idx[redo] = _nearest(tree, pts, pts[rows[redo]], rows[redo], kq, bound)
            dist[redo] = np.sqrt(_sq_dist(pts, rows[redo], idx[redo]))
        a, b, c = _pairs(rows, idx, dist, n)
        out_src[m : m + len(a)], out_dst[m : m + len(a)], out_dist[m : m + len(a)] = a, b, c
        m += len(a)
    return out_src[:m], out_dst[:m], out_dist[:m]


def _sq_dist(pts: np.ndarray, rows: np.ndarray, idx: np.ndarray) -> np.ndarray:
    """(R, c) squared distances from ``pts[rows]`` to ``pts[idx]`` (index n = "no neighbour":
    inf), summed column by column, ((dx^2 + dy^2) + dz^2) in float64: the k-d trees' own sum,
    so the same bits as their distances. ``pts``: (N, 3) float64, or its three contiguous
    columns (faster gathers: the table's edges gather 13 columns of every row)."""
    cols = [pts[:, a] for a in range(3)] if isinstance(pts, np.ndarray) else pts
    n = len(cols[0])
    none = idx >= n
    j = np.where(none, 0, idx) if none.any() else idx
    d2 = None
    for c in cols:
        # np.take on a contiguous column: the same values as c[j], faster with int32 indices
        # (session 6); a strided column (few query rows) is indexed, np.take would copy it whole
        if c.flags.c_contiguous:
            diff = np.take(c, j)
            diff -= np.take(c, rows)[:, None]
        else:
            diff = c[j]
            diff -= c[rows][:, None]
        diff *= diff
        if d2 is None:
            d2 = diff
        else:
            d2 += diff
    d2[none] = np.inf
    return d2


def _nearest(tree, pts: np.ndarray, queries: np.ndarray, rows: np.ndarray, kq: int, bound: float) -> np.ndarray:
    """(R, kq) int64 indices of the ``kq`` nearest points of each query, n (no neighbour)
    where the squared distance is >= ``bound``: what cKDTree's
    ``query(k=kq, distance_upper_bound=sqrt(bound))`` reported (its bound is strict)."""
    n = len(pts)
    kk = min(kq, n)
    _, idx = knn_query(tree, queries, kk)
    out = np.full((len(queries), kq), n, np.int64)
    out[:, :kk] = idx
    out[_sq_dist(pts, rows, out) >= bound] = n
    return out


def _pairs(rows: np.ndarray, idx: np.ndarray, dist: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (src, dst int32, dist) pairs of query rows ``rows`` (int32), dropping "no neighbour"
    (index n) and the point itself."""
    kq = idx.shape[1]
    # int32 pairs (issue 13, 1080p memory): the edge arrays are the stage's largest
    src = np.repeat(rows, kq)
    dst = idx.reshape(-1)
    ok = (dst < n) & (dst != src)
    return src[ok], dst[ok].astype(np.int32), dist.reshape(-1)[ok]


# Rows per block of the neighbour-table edges (ours: 16 Ki rows x 13 columns of float64
# temporaries, about 2 MiB each; larger blocks measured no faster).
_EDGE_BLOCK = 1 << 14

# A float32 coordinate is within half a spacing of the float64 mean it was rounded from, so a
# distance moves by at most sqrt(3) spacings between the two; a comparison of two distances
# by twice that; twice again for safety.
_ROUNDING_MARGIN = 4.0 * 3.0**0.5


def build_supervoxels(cloud: FusedCloud, cfg: SuperVoxelConfig = SuperVoxelConfig()) -> SuperVoxels:
    """Cluster the voxels of ``cloud`` into super-voxels (eq. 1) and mark the support."""
    n = cloud.num
    if n == 0:
        z = np.zeros(0)
        return SuperVoxels(np.zeros(0, np.int32), z.astype(np.int64), z, z.astype(bool), None)
    pts = cloud.points.astype(np.float64)
    # No pair farther than tau_merge / alpha can satisfy eq. 1 (the normal term is >= 0).
    max_dist = cfg.tau_merge / cfg.alpha if cfg.alpha > 0 else np.inf
    # The support rule also uses the graph (floor patch, two voxels): query far enough.
    q_dist = max(max_dist, 2.0 * cloud.voxel_size) if cfg.support_removal else max_dist
    # ours (issue 13): the support's plane fits need only the cloud, so they run on a second
    # thread while the graph and its components are built here (the same calls on the same
    # inputs: the same planes); about a third of this stage's CPU on a hard 640x480 scene. The
    # k-d tree for the few rows the neighbour table cannot answer is built there first.
    pool = ThreadPoolExecutor(1) if cfg.support_removal else None
    tree = pool.submit(knn_tree, pts) if pool is not None else None
    planes = pool.submit(support_planes, cloud, cfg) if pool is not None else None
    try:
        src, dst, dist = _knn_edges(pts, cfg.knn, q_dist, cloud.neighbours,
                                    tree.result if tree is not None else None)
        # eq. 1 in blocks of edges: the two gathered (E, 3) normal arrays were this stage's peak
        # memory at 1080p (36 MiB for 1.5 M edges); each edge's value is computed as before
        merge = np.empty(len(src), bool)
        for s in range(0, len(src), _EDGE_BLOCK * 8):
            e = slice(s, s + _EDGE_BLOCK * 8)
            # np.take of rows: the same rows as normals[src[e]], half the time (session 6: the
            # eq. 1 test 0.050 -> 0.023 s CPU for 1.5 M edges)
            dot = np.einsum("ij,ij->i", np.take(cloud.normals, src[e], axis=0),
                            np.take(cloud.normals, dst[e], axis=0)).astype(np.float64)
            if cfg.absolute_normal_dot:
                dot = np.abs(dot)
            merge[e] = cfg.alpha * dist[e] + cfg.beta * (1.0 - dot) <= cfg.tau_merge
        labels = connected_components(n, src[merge], dst[merge]).astype(np.int32)
        k = int(labels.max()) + 1
        counts = np.bincount(labels, weights=cloud.counts, minlength=k).round().astype(np.int64)
        weights = counts / max(int(counts.sum()), 1)
        if planes is not None:
            support, plane, planar = mark_support(cloud, labels, k, counts, src, dst, dist, cfg,
                                                        planes=planes.result())  # re-raises the thread's error
        else:
            support, plane, planar = np.zeros(k, bool), None, None
    finally:
        if pool is not None:  # after an error here, the fits finish and are dropped
            pool.shutdown(wait=True)
    return SuperVoxels(
        labels=labels,
        counts=counts,
        weights=weights,
        support=support,
        plane=plane,
        sizes=np.bincount(labels, minlength=k),
        planar=planar,
    )
