"""Normals without Open3D (issue 13): the pykdtree/numpy estimate equals Open3D's ``estimate_normals``.

``normals.estimate_normals`` (``pointcloud``'s) replaced Open3D's KNN PCA normals so that the segmentation
core never imports open3d (0.9 s of package init per process). These tests pin that the
two estimates agree on noisy generated surfaces and on a fused cloud, and that the closed-form
3x3 eigenvector equals LAPACK's, degenerate matrices included.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.normals import estimate_normals as _estimate_normals
from clutt3r_core.normals import smallest_eigvec as _smallest_eigvec
from clutt3r_core.pointcloud import fuse_views

from ._geometry_scenes import make_views


def _angles_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Unsigned angle between rows (PCA normals have no sign); atan2 of |a x b| and |a . b|,
    which stays exact near 0 where arccos of a float32 dot reads 0.03 degrees of round-off."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.abs(np.einsum("ij,ij->i", a, b))))


def _open3d_normals(points: np.ndarray, knn: int) -> np.ndarray:
    o3d = pytest.importorskip("open3d", reason="open3d is the reference these normals must equal")
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points.astype(np.float64)))
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamKNN(knn=knn))
    return np.asarray(pcd.normals)


def _noisy_surfaces(seed: int) -> np.ndarray:
    """A 5 mm-sampled table, a box and a sphere with 1 mm noise: planes, creases and curvature."""
    rng = np.random.default_rng(seed)
    g = np.arange(-0.2, 0.2, 0.005)
    u, v = np.meshgrid(g, g)
    table = np.column_stack([u.ravel(), v.ravel(), np.zeros(u.size)])
    b = np.arange(-0.04, 0.04, 0.005)
    bu, bv = np.meshgrid(b, b)
    faces = [np.column_stack([bu.ravel(), bv.ravel(), np.full(bu.size, 0.08)])]
    for s in (-0.04, 0.04):
        faces.append(np.column_stack([np.full(bu.size, s), bu.ravel(), bv.ravel() + 0.04]))
        faces.append(np.column_stack([bu.ravel(), np.full(bu.size, s), bv.ravel() + 0.04]))
    d = rng.normal(size=(1500, 3))
    sphere = 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True) + (0.12, 0.1, 0.05)
    pts = np.concatenate([table, *faces, sphere])
    return pts + rng.normal(scale=0.001, size=pts.shape) + (0.3, -0.2, 0.7)  # away from the origin


def _eigen_gap(points: np.ndarray, knn: int) -> np.ndarray:
    """(N,) (lambda_2 - lambda_3) / lambda_1 of each point's neighbourhood covariance."""
    from scipy.spatial import cKDTree

    _, idx = cKDTree(points).query(points, k=knn)
    d = points[idx] - points[idx].mean(axis=1, keepdims=True)
    lam = np.linalg.eigvalsh(np.einsum("nki,nkj->nij", d, d))
    return (lam[:, 1] - lam[:, 0]) / np.maximum(lam[:, 2], 1e-300)


@pytest.mark.parametrize("knn", [3, 20])
def test_normals_equal_open3d_on_noisy_surfaces(knn):
    pts = _noisy_surfaces(seed=knn)
    ours, ref = _estimate_normals(pts, knn), _open3d_normals(pts, knn)
    np.testing.assert_allclose(np.linalg.norm(ours, axis=1), 1.0, atol=1e-12)
    ang = _angles_deg(ours, ref)
    # Where the normal is defined (the two smallest eigenvalues apart) the two solvers agree
    # to round-off: measured at most ~3e-6 degrees. With knn = 3 a few nearly collinear
    # triples (lambda_2 / lambda_1 ~ 1e-8) have no defined normal; there each solver returns
    # its own vector of the near-null plane (one point, 0.6 degrees, on this cloud).
    defined = _eigen_gap(pts, knn) > 1e-6
    assert defined.mean() > 0.99
    assert ang[defined].max() < 1e-3, (ang[defined].max(), int(np.argmax(np.where(defined, ang, 0))))


def test_fused_cloud_normals_equal_open3d():
    cloud = fuse_views(make_views(3))
    pts = cloud.points.astype(np.float64)
    # on the same points the two agree everywhere (measured max 1e-6 degrees)
    assert _angles_deg(_estimate_normals(pts, 20), _open3d_normals(pts, 20)).max() < 1e-3
    # fuse_views estimates on the float64 voxel means and stores float32 points: on this
    # exact ray-cast grid a few voxels have their 20th and 21st neighbours at the same
    # distance, a tie that float32 rounding can break the other way (measured: 1 voxel of
    # 8235, 2 degrees); every other stored normal is Open3D's up to float32 storage
    ang = _angles_deg(cloud.normals.astype(np.float64), _open3d_normals(pts, 20))
    assert (ang > 1e-2).sum() <= max(1, len(pts) // 1000), np.sort(ang)[-5:]


def test_tiny_and_degenerate_clouds():
    assert _estimate_normals(np.zeros((0, 3)), 20).shape == (0, 3)
    np.testing.assert_array_equal(_estimate_normals(np.ones((2, 3)), 20), [[0, 0, 1], [0, 0, 1]])
    # all points coincident: no direction is defined; a unit vector, never NaN
    n = _estimate_normals(np.ones((5, 3)), 20)
    assert np.isfinite(n).all() and np.allclose(np.linalg.norm(n, axis=1), 1.0)
    # collinear points: any unit vector orthogonal to the line is a PCA normal
    line = np.column_stack([np.linspace(0, 1, 30), np.zeros(30), np.zeros(30)])
    n = _estimate_normals(line, 5)
    assert np.allclose(np.linalg.norm(n, axis=1), 1.0) and np.allclose(n[:, 0], 0.0, atol=1e-9)


def _sym6(m: np.ndarray) -> np.ndarray:
    return np.stack([m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], m[:, 0, 1], m[:, 0, 2], m[:, 1, 2]], axis=1)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    eig=st.tuples(*(st.sampled_from([0.0, 1e-9, 1e-4, 0.3, 1.0, 5.0]) for _ in range(3))),
    scale=st.sampled_from([1e-6, 1e-3, 1.0, 1e3]),
)
def test_smallest_eigvec_is_the_smallest_eigenvector(seed, eig, scale):
    """Property: for any symmetric PSD matrix (repeated and zero eigenvalues included) the
    result is a unit vector v with A v = lambda_min v, the eigenvalue LAPACK reports."""
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    A = scale * (q @ np.diag(eig) @ q.T)
    A = 0.5 * (A + A.T)
    v = _smallest_eigvec(_sym6(A[None]))[0]
    lam = np.linalg.eigvalsh(A)[0]
    assert abs(np.linalg.norm(v) - 1.0) < 1e-9
    top = max(abs(np.linalg.eigvalsh(A)).max(), 1e-300)
    # residual relative to the largest eigenvalue: the accuracy any 3x3 solver has
    assert np.linalg.norm(A @ v - lam * v) <= 1e-6 * top + 1e-300


def test_smallest_eigvec_matches_eigh_on_random_covariances():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(2000, 20, 3)) * (1.0, 0.5, 0.01)  # plane-like neighbourhoods
    x = x @ np.linalg.qr(rng.normal(size=(3, 3)))[0]
    d = x - x.mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", d, d) / 20
    ours = _smallest_eigvec(_sym6(cov))
    ref = np.linalg.eigh(cov)[1][:, :, 0]
    assert _angles_deg(ours, ref).max() < 1e-5


def test_normals_and_neighbours_do_not_depend_on_the_block_size_or_threads(monkeypatch):
    """Issue 13: the estimate runs in blocks of rows (memory at 1080p); each row's normal and
    neighbour list must be the same bits whatever block it falls in, and the table is the
    k-NN query's (the super-voxel graph reuses it)."""
    import clutt3r_core.normals as pc
    from scipy.spatial import cKDTree

    pts = _noisy_surfaces(seed=5)
    whole, table = None, None
    # (covariance block, query block, threads): the query block need not be a multiple of the
    # other; query blocks run on threads (any order of completion)
    for block, qblock, workers in ((1 << 20, 1 << 20, 1), (4096, 1 << 16, 1), (997, 3000, 3), (7, 5, 2),
                                   (4096, 1, 4), (4096, 3000, 1)):
        monkeypatch.setattr(pc, "_NORMAL_BLOCK", block)
        monkeypatch.setattr(pc, "_QUERY_BLOCK", qblock)
        monkeypatch.setattr(pc, "_max_workers", lambda w=workers: w)
        nrm, tab = _estimate_normals(pts, 20, neighbours=True)
        if whole is None:
            whole, table = nrm, tab
            np.testing.assert_array_equal(tab, cKDTree(pts).query(pts, k=20)[1])
            assert tab.dtype == np.int32
        np.testing.assert_array_equal(nrm, whole)
        np.testing.assert_array_equal(tab, table)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(3, 300), k=st.integers(1, 25), grid=st.booleans())
def test_knn_query_is_the_exact_knn_with_ties_by_index(seed, n, k, grid):
    """Property (issue 13: pykdtree replaced scipy's cKDTree): each row holds the k nearest
    points with exactly cKDTree's float64 distances, ascending, equal distances by index; the
    points strictly nearer than the k-th distance are cKDTree's (at the k-th distance itself
    either tree may keep any of the tied points). Grid points make many exact ties."""
    from scipy.spatial import cKDTree

    from clutt3r_core.normals import knn_query, knn_tree

    rng = np.random.default_rng(seed)
    if grid:  # voxel means on a millimetre grid: many exactly equal distances
        pts = rng.integers(0, 8, (n, 3)) * 0.004 + np.array([0.31, -0.2, 0.7])
    else:
        pts = rng.random((n, 3)) * 0.08 + np.array([0.31, -0.2, 0.7])
    k = min(k, n)
    d2, idx = knn_query(knn_tree(pts), pts, k)
    assert idx.dtype == np.int32 and idx.shape == (n, k) and d2.shape == (n, k)
    ref_d, ref_i = cKDTree(pts).query(pts, k=k)
    ref_d, ref_i = ref_d.reshape(n, k), ref_i.reshape(n, k)
    np.testing.assert_array_equal(np.sqrt(d2), ref_d)
    # the distances really are those of the returned points, summed as the trees sum them
    diff = pts[idx] - pts[:, None, :]
    np.testing.assert_array_equal(d2, (diff[..., 0] ** 2 + diff[..., 1] ** 2) + diff[..., 2] ** 2)
    assert (np.diff(d2, axis=1) >= 0).all()
    tie = np.diff(d2, axis=1) == 0
    assert (np.diff(idx.astype(np.int64), axis=1)[tie] > 0).all()  # ties by ascending index
    for r in range(n):
        inner = d2[r] < d2[r, -1]
        assert set(idx[r, inner].tolist()) == set(ref_i[r, inner].tolist())
    if not grid:  # no ties: the very same table as cKDTree's
        np.testing.assert_array_equal(idx, ref_i)


def test_one_openmp_thread_limits_and_restores_pykdtree_openmp():
    """The cached controller (issue 13: one library scan, not one per query) limits the k-d
    tree's OpenMP library to one thread inside the block and restores it after."""
    from threadpoolctl import ThreadpoolController

    from clutt3r_core import normals

    normals.knn_tree(np.random.default_rng(0).random((10, 3)))  # pykdtree (and its OpenMP) loaded

    def counts():
        return [i["num_threads"] for i in ThreadpoolController().select(user_api="openmp").info()]

    before = counts()
    if not before:
        pytest.skip("this pykdtree build has no OpenMP library")
    with normals._one_openmp_thread():
        assert counts() == [1] * len(before)
    assert counts() == before
