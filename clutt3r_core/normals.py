"""Unoriented PCA normals of a point cloud (the fusion's, Sec. III-A, and the update's ICP models).

Split out of ``pointcloud`` so that every caller shares one estimate (the update's point-to-plane
registration had its own k-NN + ``eigh`` copy).
"""

from __future__ import annotations

import os

import numpy as np

__all__ = ["estimate_normals", "knn_query", "knn_tree", "smallest_eigvec"]

# Points per block of the normal estimation: bounds the (block, knn) neighbour
# offsets, distances and indices (about 5 x 20 x 4 Ki x 8 B = 3 MiB); measured on
# sample_seq4 the stage's traced peak is 27 MiB with 4 Ki blocks and 43 MiB with 16 Ki
# ones, at the same speed (issue 13, 1080p memory). Each row's result is independent of
# the block it falls in (the same bits, tests/core/test_normals.py).
_NORMAL_BLOCK = 1 << 12
# Points per k-NN query, the unit of work of the normals' threads (``_max_workers``); a query
# holds (rows, knn) float64 distances and int32 indices. Measured on sample_seq4 with 2 threads
# the stage's traced peak is 32 MiB with 8 Ki rows, 36 MiB with 16 Ki (27 MiB with cKDTree's
# 4 Ki blocks on one thread before), the time the same within the machine's noise.
_QUERY_BLOCK = 1 << 13
# Fewer queries than this run on one thread (knn_query).
_PARALLEL_MIN_QUERIES = 1 << 12


_OPENMP = None


def _one_openmp_thread():
    """A context limiting the OpenMP libraries loaded now (pykdtree's, once a tree exists) to one
    thread for the calling thread. The controller is made once: ``threadpool_limits`` scans
    every loaded library on each call (0.5-3 ms of CPU, and the normals and super-voxels make
    about 30 such calls per 640x480 segmentation; issue 13)."""
    global _OPENMP
    if _OPENMP is None or not _OPENMP.lib_controllers:  # none loaded yet: look again next time
        from threadpoolctl import ThreadpoolController

        _OPENMP = ThreadpoolController().select(user_api="openmp")
    return _OPENMP.limit(limits=1)


def _max_workers() -> int:
    """Threads for the normals' blocks: the CPUs this process may use, at most 4 (ours: the
    blocks share the GIL between numpy calls; 2 threads on the project's 2-core machine)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cpus = os.cpu_count() or 1
    return max(1, min(4, cpus))


def knn_tree(points: np.ndarray):
    """A k-d tree over (N, 3) float64 ``points`` (C-contiguous) for ``knn_query``.

    pykdtree's (issue 13): on a hard 640x480 scene (157 k voxels, k = 20) its query takes
    0.33 s of CPU where scipy's cKDTree took 0.51 s, and importing it takes 1 ms where
    ``scipy.spatial`` takes 0.09 s (its package init loads qhull, scipy.linalg and
    scipy.special, none of which the segmentation uses). Its distances are the same float64
    sums as cKDTree's, so the neighbours are the same up to the order of equal distances
    (``knn_query``); a query runs on OpenMP threads (all cores, unless limited; the results
    do not depend on their number).
    """
    from pykdtree.kdtree import KDTree

    return KDTree(np.ascontiguousarray(points, dtype=np.float64))


def knn_query(tree, queries: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The ``k`` nearest tree points of each row of ``queries`` (Q, 3) float64:
    ((Q, k) float64 squared distances, ascending, (Q, k) int32 indices).

    Equal distances within a row are ordered by index (ours): the tree's own order of
    ties depends on how it was built, and the order sets the summation order, so the bits,
    of the normals' covariances. Which of several points tied at the k-th distance is
    kept is the tree's choice (about 1 row in 10^5 on the generated scenes).

    Fewer than ``_PARALLEL_MIN_QUERIES`` rows are queried on one thread: an OpenMP region
    costs its threads' start and barrier, measured 7 ms of CPU for 74 rows on a loaded
    2-core machine against 0.2 ms on one thread.
    """
    q = np.ascontiguousarray(queries, dtype=np.float64)
    if len(q) < _PARALLEL_MIN_QUERIES:
        with _one_openmp_thread():
            d2, idx = tree.query(q, k=k, sqr_dists=True)
    else:
        d2, idx = tree.query(q, k=k, sqr_dists=True)
    d2 = d2.reshape(len(q), k)
    # uint32 below 2^31 points: the same values as int32
    idx = (idx.view(np.int32) if idx.dtype == np.uint32 else idx.astype(np.int32)).reshape(len(q), k)
    if k > 1:
        tie = np.flatnonzero((d2[:, 1:] == d2[:, :-1]).any(axis=1))
        if len(tie):
            # lexsort per row: distance first, then index (a handful of rows per scene)
            order = np.lexsort((idx[tie], d2[tie]), axis=1)
            idx[tie] = np.take_along_axis(idx[tie], order, axis=1)
            d2[tie] = np.take_along_axis(d2[tie], order, axis=1)
    return d2, idx


def estimate_normals(points: np.ndarray, knn: int, *, neighbours: bool = False):
    """(N, 3) float64 unit PCA normals, unoriented: the eigenvector of the smallest
    eigenvalue of the covariance of each point's ``knn`` nearest points (itself included).
    With ``neighbours=True``, returns (normals, (N, min(knn, N)) int32 neighbour indices,
    nearest first, equal distances by index (``knn_query``); None for fewer than 3 points).

    The same estimate as Open3D's ``PointCloud.estimate_normals(KDTreeSearchParamKNN(knn))``,
    which this replaced (issue 13): ``import open3d`` costs about 0.9 s per process
    because its package init loads its plotly/dash visualisation, and normals were the
    only thing the segmentation core used it for. Measured against Open3D 0.20 on a hard
    generated scene (157 k voxels) and on sample_seq4 the two differ by at most a few
    micro-degrees (tests/core/test_normals.py). Neighbours come from ``knn_tree`` /
    ``knn_query``; the eigenvector is the closed form for a symmetric 3x3 matrix
    (``smallest_eigvec``). Blocks of ``_QUERY_BLOCK`` rows run on up to ``_max_workers()``
    threads, each query on one thread: on a hard 640x480 scene (loaded 2-core machine, 8
    alternating runs) 0.48 s wall / 0.49 s CPU against 0.66 / 0.57 with the blocks in turn
    and each query on OpenMP's two threads; the same bits (tests/core/test_normals.py).
    """
    n = points.shape[0]
    if n < 3:
        nrm = np.tile([0.0, 0.0, 1.0], (n, 1))
        return (nrm, None) if neighbours else nrm
    pts = np.ascontiguousarray(points, dtype=np.float64)
    k = min(knn, n)
    tree = knn_tree(pts)
    cols = [np.ascontiguousarray(pts[:, a]) for a in range(3)]
    nrm = np.empty((n, 3))
    table = np.empty((n, k), np.int32) if neighbours else None

    def block(s0: int) -> None:  # one k-NN query of _QUERY_BLOCK rows, then their covariances
        _, qidx = knn_query(tree, pts[s0 : s0 + _QUERY_BLOCK], k)
        for s in range(s0, s0 + len(qidx), _NORMAL_BLOCK):
            q = pts[s : min(s + _NORMAL_BLOCK, s0 + len(qidx))]
            idx = qidx[s - s0 : s - s0 + len(q)].astype(np.intp)
            if table is not None:
                table[s : s + len(q)] = idx
            # offsets from the query point: the covariance is translation-free, and centring
            # on a nearby point keeps the sums small (no cancellation at metres from the origin)
            d = [c[idx] - q[:, a, None] for a, c in enumerate(cols)]
            m = [x.mean(axis=1) for x in d]
            cov = np.empty((len(q), 6))
            for j, (a, b) in enumerate(((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))):
                cov[:, j] = np.einsum("ij,ij->i", d[a], d[b]) / k - m[a] * m[b]
            nrm[s : s + len(q)] = smallest_eigvec(cov)

    starts = range(0, n, _QUERY_BLOCK)
    workers = min(_max_workers(), len(starts))
    if workers > 1:
        # blocks on threads (numpy and the query release the GIL), each query on its own
        # thread only (OpenMP's thread count is per calling thread): every row's result is
        # computed as in one thread, the same bits
        from concurrent.futures import ThreadPoolExecutor

        def one_thread_block(s0: int) -> None:
            with _one_openmp_thread():
                block(s0)

        with ThreadPoolExecutor(workers) as ex:
            for _ in ex.map(one_thread_block, starts):  # re-raises a block's error
                pass
    else:
        for s0 in starts:
            block(s0)
    bad = ~np.isfinite(nrm).all(axis=1) | (np.linalg.norm(nrm, axis=1) < 0.5)
    nrm[bad] = (0.0, 0.0, 1.0)  # degenerate neighbourhoods (coincident voxels); oriented later
    return (nrm, table) if neighbours else nrm


def smallest_eigvec(c6: np.ndarray) -> np.ndarray:
    """(M, 3) unit eigenvector of the smallest eigenvalue of each symmetric 3x3 matrix
    given as (M, 6) [a00, a11, a22, a01, a02, a12].

    Closed form (about 4x cheaper than batched ``np.linalg.eigh``): the smallest
    eigenvalue by the trigonometric solution of the characteristic cubic, then the null
    vector of A - lambda I as the largest cross product of two of its rows. Rows where
    that is not well defined (a repeated smallest eigenvalue: collinear or coincident
    neighbours, where every cross product vanishes) fall back to ``np.linalg.eigh``.
    """
    scale = np.abs(c6).max(axis=1)
    scale[scale == 0] = 1.0
    a00, a11, a22, a01, a02, a12 = (c6 / scale[:, None]).T
    q = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - q, a11 - q, a22 - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (a01 * a01 + a02 * a02 + a12 * a12)) / 6.0)
    pinv = np.divide(1.0, p, out=np.zeros_like(p), where=p > 0)
    c00, c11, c22, c01, c02, c12 = (x * pinv for x in (b00, b11, b22, a01, a02, a12))
    det = c00 * (c11 * c22 - c12 * c12) - c01 * (c01 * c22 - c12 * c02) + c02 * (c01 * c12 - c11 * c02)
    lam = q + 2.0 * p * np.cos(np.arccos(np.clip(det / 2.0, -1.0, 1.0)) / 3.0 + 2.0 * np.pi / 3.0)
    r0 = np.stack([a00 - lam, a01, a02], axis=1)
    r1 = np.stack([a01, a11 - lam, a12], axis=1)
    r2 = np.stack([a02, a12, a22 - lam], axis=1)
    cands = (np.cross(r0, r1), np.cross(r0, r2), np.cross(r1, r2))
    sq = np.stack([np.einsum("ij,ij->i", v, v) for v in cands], axis=1)
    best = sq.argmax(axis=1)
    rows = np.arange(len(best))
    out = np.choose(best[:, None], cands) / np.sqrt(np.maximum(sq[rows, best], 1e-300))[:, None]
    # |cross|^2 of two unit-scale rows: ~1e-4 and up for a plane of voxels; tiny when the
    # null space is 2-D (or 3-D), where the cross products are round-off
    weak = sq[rows, best] < 1e-10
    if weak.any():
        w = np.flatnonzero(weak)
        A = np.empty((len(w), 3, 3))
        A[:, 0, 0], A[:, 1, 1], A[:, 2, 2] = a00[w], a11[w], a22[w]
        A[:, 0, 1] = A[:, 1, 0] = a01[w]
        A[:, 0, 2] = A[:, 2, 0] = a02[w]
        A[:, 1, 2] = A[:, 2, 1] = a12[w]
        out[w] = np.linalg.eigh(A)[1][:, :, 0]
    return out
