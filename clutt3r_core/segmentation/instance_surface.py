"""Per-instance surface step after the labelling (ours, issue 13; off by default, below).

The fused cloud of noisy depth is thicker than the surface even after the multi-view estimate
(``clutt3r_core.surface``): the residual of an object's fused points about the clean surface is
about 1.3 mm (std) on generated RealSense-like scenes, and the points that cross a 10 mm cell face
are the "off_gt" cells of ``evaluation.breakdown``. A moving-least-squares projection of the
whole cloud was measured before (docs/benchmark/strict-iou.md: +9.6 / -3.3 / -4.2 AP): it averages
object and table points across the contact, pulling both towards a surface that is neither.

Here every labelled instance is smoothed with its **own** points only, after the vote: each point
is projected onto a quadric height field fitted (Gaussian-weighted least squares) to its ``k``
nearest same-instance neighbours within ``radius`` in the frame of their principal axes, so that
the surfaces of two touching objects, or of an object and the table, are never averaged together.
A quadric, not a plane: a plane fitted over 10 mm of a 3 cm-radius object lies ~0.8 mm inside
its surface (the sagitta), the size of the noise removed. A move longer than ``max_move`` is
refused (the point keeps its position): a corner or a wrongly labelled sliver is not noise.
Neighbours weigh their raw point counts (a voxel of one raw point is noisier than a voxel of ten).
A fused point is the mean of the raw points in its 5 mm voxel, and it stands for the surface in
that voxel: where the fitted surface crosses the point's voxel the point goes to the surface
inside it; where it misses the voxel, the voxel is off the surface and its point moves onto the
surface (into the next voxel). Unlabelled points (-1: table, background) are left where they are
unless ``include_unlabelled``.

Measured (docs/benchmark/strict-iou.md, session 8; generated RealSense-like scenes, 10 mm): AP
+1.5 (tuning seeds 2-3) and +4.2 (check seeds 0-1), AP25 / AP50 unchanged, the labelled points'
distance to the clean surface 15 % lower (median) and 25 % lower (90th percentile); off by
default because the real sample_seq1 update reads two instances differently (a status that
random 0.1-0.4 mm noise of the stored points tips as well) and two objects of one scene lose
their only grasps.

Pure numpy / scipy (cKDTree). Only points move: labels, counts, colours, normals stay.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["InstanceSurfaceConfig", "SmoothedPoints", "smooth_instances"]


@dataclass(frozen=True)
class InstanceSurfaceConfig:
    """Parameters of the per-instance surface step (ours, issue 13; ``radius`` 0 = off)."""

    radius: float = 0.0
    """Neighbourhood radius of the local fit, metres; 0 = off (the default and the paper's text).
    Ours when on: 0.010 (tuning seeds 2-3, mean AP 8 / 10 / 12 mm: 52.1 / 53.2 / 52.3, off 51.7)."""
    k: int = 20
    """Nearest same-instance neighbours fitted (at most; those within ``radius``)."""
    min_neighbours: int = 8
    """Fewer neighbours (the point itself included) within ``radius`` = the point stays (a quadric
    needs 6, and a few more to average the noise)."""
    max_move: float = 0.004
    """A projection longer than this keeps the point where it is, metres."""
    count_weights: bool = True
    """Neighbours weigh their raw point counts (``smooth_instances``): measured on tuning scenes,
    voxels of one raw point are off the GT cells 11-15 % of the time, voxels of 9 or more 0.5-3 %."""
    keep_in_voxel: bool = True
    """Where the fitted surface crosses the point's fusion voxel (``smooth_instances``'s
    ``voxel_size``), the point goes to the surface inside that voxel (module docstring); else, and
    when False, to the projection. Without it the projections moved points closer to the GT
    surface but out of the thin slivers a surface clips at a cell corner (tuning scenes: 41 / 136
    GT object cells lost on easy_0002 / hard_0002; hard_0002 AP 46.7 -> 44.7, with it 49.0)."""
    leave_margin: float = 0.0
    """With ``keep_in_voxel``: a point leaves its voxel only when the fitted surface misses the voxel
    by more than this, metres (a surface that clips a cell's corner by less than the fit's own
    error keeps its sample there)."""
    include_unlabelled: bool = False
    """Also smooth the unlabelled points (-1) among themselves (the table and background)."""

    def __post_init__(self) -> None:
        if self.radius < 0 or self.max_move <= 0 or self.leave_margin < 0:
            raise SceneError("InstanceSurfaceConfig: radius and leave_margin must be >= 0 and max_move > 0 (metres)")
        if self.k < 6 or self.min_neighbours < 6 or self.min_neighbours > self.k:
            raise SceneError("InstanceSurfaceConfig: need 6 <= min_neighbours <= k (a quadric has 6 unknowns)")

    @property
    def enabled(self) -> bool:
        return self.radius > 0


@dataclass(frozen=True, eq=False)
class SmoothedPoints:
    """Result of ``smooth_instances``.

    Attributes:
        points: (N, 3) float32 world metres, the moved points (unmoved ones as given).
        moved: (N,) bool, the points that moved.
        shift: (N,) float32 metres, the length of each point's move (0 where it stayed).
    """

    points: np.ndarray
    moved: np.ndarray
    shift: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.points)
        if self.points.shape != (n, 3) or self.moved.shape != (n,) or self.shift.shape != (n,):
            raise SceneError("SmoothedPoints: points (N, 3), moved (N,) and shift (N,) must agree")


def _project(q: np.ndarray, nb: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projections of q (M, 3) onto the weighted quadric of its neighbours nb (M, K, 3),
    weights w (M, K) (0 = not a neighbour). Returns the projections (M, 3) and the fit's unit normals there
    (M, 3); NaN where the fit is degenerate."""
    ws = w.sum(1, keepdims=True)
    c = (nb * w[..., None]).sum(1) / ws  # weighted centroid (M, 3)
    X = nb - c[:, None]
    cov = np.einsum("mk,mki,mkj->mij", w, X, X)
    _, vec = np.linalg.eigh(cov)  # ascending: column 0 = normal, 1-2 = tangents
    u = np.einsum("mki,mi->mk", X, vec[:, :, 2])
    v = np.einsum("mki,mi->mk", X, vec[:, :, 1])
    h = np.einsum("mki,mi->mk", X, vec[:, :, 0])
    qx = q - c
    qu, qv, qh = (np.einsum("mi,mi->m", qx, vec[:, :, j]) for j in (2, 1, 0))
    # height field h = a + b u + c v + d u^2 + e uv + f v^2, centred on the query point's (u, v)
    du, dv = u - qu[:, None], v - qv[:, None]
    terms = [np.ones_like(du), du, dv, du * du, du * dv, dv * dv]
    A = np.stack(terms, axis=-1)  # (M, K, 6)
    Aw = A * w[..., None]
    N = np.einsum("mki,mkj->mij", Aw, A) + 1e-12 * np.eye(len(terms))
    rhs = np.einsum("mki,mk->mi", Aw, h)
    try:
        coef = np.linalg.solve(N, rhs[..., None])[..., 0]
    except np.linalg.LinAlgError:  # one singular system fails the batch: solve one by one
        coef = np.full((len(q), len(terms)), np.nan)
        for i in range(len(q)):
            try:
                coef[i] = np.linalg.solve(N[i], rhs[i])
            except np.linalg.LinAlgError:
                pass
    # the height at the query's own (u, v) is the constant term; move along the fit's normal
    n = vec[:, :, 0] - coef[:, 1:2] * vec[:, :, 2] - coef[:, 2:3] * vec[:, :, 1]  # normal of the height field
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    return q + (coef[:, 0] - qh)[:, None] * vec[:, :, 0], n


def _into_voxel(p: np.ndarray, proj: np.ndarray, n: np.ndarray, vs: float, margin: float = 0.0) -> np.ndarray:
    """Where the fitted surface (its tangent plane at ``proj``, normal ``n``) crosses the voxel of
    ``p``, the point of that plane inside the voxel nearest to ``proj`` (alternating projections);
    elsewhere ``proj`` itself: a voxel the local surface does not pass through is off the
    surface, and its point joins the surface in the voxel next to it. A plane that misses the voxel
    by less than ``margin`` (metres) counts as crossing it (the point goes to the voxel's point
    nearest to the plane)."""
    lo = np.floor(p / vs) * vs
    eps = 1e-6 * vs
    centre = lo + 0.5 * vs
    with np.errstate(invalid="ignore"):
        crosses = np.abs(np.einsum("ni,ni->n", centre - proj, n)) <= 0.5 * vs * np.abs(n).sum(1) + margin
    x = proj[crosses]
    nn, l0 = n[crosses], lo[crosses]
    for _ in range(8):
        x = np.clip(x, l0 + eps, l0 + vs - eps)
        x = x - np.einsum("ni,ni->n", x - proj[crosses], nn)[:, None] * nn
    out = proj.copy()
    out[crosses] = np.clip(x, l0 + eps, l0 + vs - eps)
    return out


def smooth_instances(points: np.ndarray, instance: np.ndarray, cfg: InstanceSurfaceConfig,
                     counts: np.ndarray | None = None, voxel_size: float = 0.0) -> SmoothedPoints:
    """Each instance's points projected onto a local quadric of that instance's own points.

    points (N, 3) world metres, instance (N,) int (-1 = unlabelled, left alone unless
    ``cfg.include_unlabelled``), counts (N,) raw points per fused voxel or None (all 1): with
    ``cfg.count_weights`` a neighbour weighs its count (a voxel mean of n raw points has 1/n of
    one point's noise variance). ``voxel_size`` > 0 (metres, the fusion's voxel): with
    ``cfg.keep_in_voxel`` a point stays in its voxel where the fitted surface crosses it.
    Deterministic; a point with fewer than ``cfg.min_neighbours`` same-instance points within
    ``cfg.radius`` (itself included), or whose move would exceed ``cfg.max_move``, stays.
    """
    from scipy.spatial import cKDTree

    p = np.asarray(points)
    lab = np.asarray(instance).reshape(-1)
    if p.ndim != 2 or p.shape[1] != 3 or len(lab) != len(p):
        raise SceneError(f"smooth_instances: points must be (N, 3) with (N,) labels, got {p.shape}, {lab.shape}")
    out = p.astype(np.float64, copy=True)
    nrm = np.full((len(p), 3), np.nan)
    if not cfg.enabled or not len(p):
        return SmoothedPoints(p.astype(np.float32), np.zeros(len(p), bool), np.zeros(len(p), np.float32))
    sigma = cfg.radius / 2.0  # Gaussian weight: the radius is 2 sigma
    cnt = None
    if cfg.count_weights and counts is not None:
        cnt = np.asarray(counts, np.float64).reshape(-1)
        if len(cnt) != len(p):
            raise SceneError(f"smooth_instances: {len(p)} points but {len(cnt)} counts")
        cnt = np.maximum(cnt, 1.0)
    ids = np.unique(lab)
    for k in ids:
        if k < 0 and not cfg.include_unlabelled:
            continue
        idx = np.flatnonzero(lab == k)
        if len(idx) < cfg.min_neighbours:
            continue
        q = p[idx].astype(np.float64)
        kk = min(cfg.k, len(idx))
        d, nn = cKDTree(q).query(q, k=kk, distance_upper_bound=cfg.radius)
        d, nn = d.reshape(len(q), kk), nn.reshape(len(q), kk)
        ok = np.isfinite(d)
        # the points with fewer neighbours stay (a plane fit for those with 3-7, measured on 3
        # tuning scenes, changed no evaluation cell)
        sel = np.flatnonzero(ok.sum(1) >= cfg.min_neighbours)
        if not len(sel):
            continue
        ok_s, nn_s = ok[sel], np.where(ok[sel], nn[sel], 0)
        nb = q[nn_s]
        w = np.where(ok_s, np.exp(-0.5 * (np.where(ok_s, d[sel], 0.0) / sigma) ** 2), 0.0)
        if cnt is not None:
            w = w * cnt[idx][nn_s]
        # blocks bound the (M, K, 6, 6) temporaries
        for s in range(0, len(sel), 20000):
            b = slice(s, s + 20000)
            out[idx[sel[b]]], nrm[idx[sel[b]]] = _project(q[sel[b]], nb[b], w[b])
    if cfg.keep_in_voxel and voxel_size > 0:
        # the fusion's invariant: a voxel's point (the mean of the raw points in it) lies in that
        # voxel; a projection that leaves it takes the voxel's point nearest to it
        out = _into_voxel(p.astype(np.float64), out, nrm, voxel_size, cfg.leave_margin)
    shift = np.linalg.norm(out - p, axis=1)
    bad = ~np.isfinite(shift) | (shift > cfg.max_move)
    out[bad] = p[bad]
    shift = np.where(bad, 0.0, shift)
    return SmoothedPoints(out.astype(np.float32), shift > 0, shift.astype(np.float32))
