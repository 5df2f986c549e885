"""Multi-view surface estimate for the fusion: raw points snapped onto a TSDF zero crossing (ours, issue 13).

Plain voxel fusion (``pointcloud.fuse_views``) keeps every 5 mm voxel that 3 raw points reach.
Sensor depth noise (about 2 mm at 0.6 m, part of it correlated over a few centimetres of one
view) spreads the raw points of a surface over a band 2-4 voxels thick, so the fused cloud is
thicker than the surface and spills into neighbouring evaluation cells ("off_gt" in
``evaluation.breakdown``).

This module estimates the surface across views first, KinectFusion-style (Newcombe et al.
2011, "truncated signed distance function"), but only where raw points landed:

1. every voxel that holds at least one raw point is a candidate;
2. every candidate voxel centre is projected into every view and the view's depth is read there
   (a plane fitted to the 5x5 pixels around it where they are smooth, which averages the white
   part of the noise and corrects for the distance to the pixel centre; the raw pixel at depth
   edges): the projective signed distance ``s = depth - z(centre)`` (positive in front of the
   surface that view measured) counts when ``|s| <= truncation``;
3. the distance field of a voxel is the mean over its views. A projective distance is
   ``1 / |cos|`` of the euclidean one, so that mean jumps where the set of views that see a
   voxel changes (occlusion edges, view borders); the field is therefore made euclidean with the
   normal of its first gradient (``E = -n . mean(s_j r_j)``, r_j the unit ray of view j), and
   differentiated again (central differences over the 6-neighbours, one voxel further where a
   band is one voxel thick);
4. every raw point moves to the zero crossing along the gradient of its voxel
   (``p - E(p) g / |g|^2`` with ``E(p)`` linearised from the voxel centre); points whose voxel
   has no usable gradient, or that would move more than ``max_shift`` or more than ``noise_k``
   times the noise measured in the moves themselves (at the point's depth), keep their raw
   position: on clean depth the estimate's rare errors (2-4 mm at rims, where the set of views
   changes) are far beyond that noise, on noisy depth the noise's own moves are within it;
5. the moved points are then voxel-averaged as before and a pixel maps to the voxel its moved
   point lands in. A voxel is kept when ``min_points`` moved points land in it, or one point
   moved from a voxel that held ``min_points`` raw points (a well observed surface that only
   clips the voxel's corner puts few samples in it), or, when switched on, when it holds a single
   point that could not be moved and borders kept voxels (a *rim* voxel,
   ``PointCloudConfig.surface_rim_neighbours``): object rims, where depth edges and grazing views
   leave sparse samples and the field no usable gradient, were the largest share of the GT object
   cells without a fused point. The fusion keeps rim voxels apart (``FusedCloud.rim``): segmented
   with the cloud they cost hard AP50, labelled after the vote by their neighbours they do not
   (``PointCloudConfig.surface_rim_attach_k``, docs/benchmark/strict-iou.md). Two wider rim rules,
   off by default (measured no gain, session 9): lone *moved* points next to kept voxels
   (``surface_rim_moved``) and lone unmoved points with a kept voxel within a reach
   (``surface_rim_reach``).

Whether to run it at all is decided from the data (``PointCloudConfig.surface = "auto"``, ours'
default): ``depth_agreement.depth_disagreement`` measures how much the views disagree about the surface, and the
estimate runs from ``PointCloudConfig.surface_auto_sigma`` (1 mm) on; ``surface_points`` is the
fusion's hook and returns a ``SurfaceChoice`` with what was measured and done.

(About 590 lines, on purpose: the field, the snap and the keep rule above are one algorithm
whose steps share the candidate-voxel tables; split apart they would pass those tables around.)

Free-space carving (dropping voxels that other views see through) was tried and measured no
gain on generated scenes (docs/benchmark/strict-iou.md); on clean depth it removed true surface
seen at grazing angles, whose projective distance exceeds the truncation. It is not done.

Pure numpy / scipy.ndimage; no open3d (its import alone costs about 0.9 s).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from clutt3r_core.depth_agreement import depth_disagreement
from clutt3r_core.errors import SceneError
from clutt3r_core.scene import View

__all__ = ["SurfaceParams", "SnappedPoints", "snap_to_surface", "smooth_depth", "SurfaceChoice", "surface_points"]


@dataclass(frozen=True)
class SurfaceParams:
    """Parameters of the surface estimate (ours, issue 13; set a priori from the sensor model, not
    swept, except where a measurement is named: docs/benchmark/strict-iou.md)."""

    voxel_size: float = 0.005
    """Voxel edge of the distance field, metres (the fusion's voxel)."""
    truncation: float = 0.015
    """A view's projective distance counts only within +-this, metres: about 4 sigma of the
    generated RealSense-like noise at 0.75 m (white + correlated, ~3.6 mm), so every view of a
    surface counts while surfaces 1.5 cm behind or in front (another object) do not."""
    smooth_px: int = 5
    """Window of the plane fitted to each view's depth, pixels of the sampled grid; 1 = the raw
    pixel. Measured on 3 tuning scenes (first version, ``min_points`` 2): 1 / 3 / 5 px gave
    hole 10.9 / 11.8 / 11.5 % and off-surface 11.2 / 9.8 / 9.3 % of the object cells."""
    edge_std: float = 0.004
    """Windows whose depths scatter more than this about the fitted plane (metres) are a depth
    edge: the raw pixel is read there (the RealSense-like white noise is ~1.5 mm at 0.6 m)."""
    max_shift: float = 0.010
    """Points whose move would exceed this keep their raw position, metres (two voxels: farther
    than any noise of the sensor model, so such a move is a bad gradient, not noise)."""
    noise_k: float = 6.0
    """A move longer than this many times the noise of the point's own depth, as measured in the
    data, is refused (0 = only ``max_shift``). The noise is the robust spread of the proposed
    moves themselves (1.4826 x median), per squared depth as a stereo camera's error grows
    (``snap_to_surface``): on clean 1 mm-quantised depth it is about 0.6 mm at 1 m, and the limit
    refuses the 2-4 mm moves of rim voxels, whose gradient tilts where the set of views that see
    them changes; with RealSense-like noise it is about 4.5 mm at 1 m and leaves the noise's own
    moves alone. Measured on the tuning scenes (seeds 2-3, 6 scenes, docs/benchmark/strict-iou.md),
    mean AP over the pipeline, clean / RealSense-like depth: no limit 65.2 / 48.2, 4 -> 72.3 /
    46.8, 6 -> 71.4 / 48.5 (plain fusion 68.6 / 39.1); 6 keeps the noisy-depth
    gain whole and AP50 on clean depth at the plain fusion's 97.8 (4: 95.4)."""
    min_points: int = 3
    """Raw points a voxel needed for its moved points to be trusted (the fusion's ``min_points``)."""
    min_depth: float = 0.05
    """Nearest depth read, metres (the fusion's)."""
    max_depth: float = 3.0
    """Farthest depth read, metres (the fusion's)."""

    def __post_init__(self) -> None:
        if not (self.voxel_size > 0 and self.truncation > 0 and self.max_shift > 0 and self.edge_std > 0):
            raise SceneError("SurfaceParams: voxel_size, truncation, max_shift and edge_std must be > 0")
        if self.smooth_px < 1:
            raise SceneError(f"SurfaceParams.smooth_px must be >= 1, got {self.smooth_px}")


@dataclass(frozen=True, eq=False)
class SnappedPoints:
    """Raw points moved onto the multi-view surface.

    Attributes:
        points: (P, 3) float32 world metres, moved (or raw where no estimate exists).
        moved: (P,) bool, the point was moved onto the estimated surface.
        trusted: (P,) bool, moved from a voxel that held at least ``min_points`` raw points: a
            sample of a well observed surface, which keeps its voxel even alone (a surface that
            only clips a corner of the voxel puts few samples in it).
        move_noise: the noise the moves were limited by, metres of depth at 1 m (robust spread of
            the proposed moves per squared depth; ``SurfaceParams.noise_k``); NaN when not measured.
    """

    points: np.ndarray
    moved: np.ndarray
    trusted: np.ndarray
    move_noise: float = float("nan")

    def __post_init__(self) -> None:
        p = np.asarray(self.points)
        if p.ndim != 2 or p.shape[1] != 3:
            raise SceneError(f"SnappedPoints.points must be (P, 3), got {p.shape}")
        for name in ("moved", "trusted"):
            if np.shape(getattr(self, name)) != (len(p),):
                raise SceneError(f"SnappedPoints.{name} must be ({len(p)},) like points")


def _box_sums(a: np.ndarray, r: int) -> np.ndarray:
    """(H + 1, W + 1) float64 integral image of ``a`` padded by ``r`` on each side, for box sums."""
    c = np.zeros((a.shape[0] + 2 * r + 1, a.shape[1] + 2 * r + 1))
    c[r + 1 : r + 1 + a.shape[0], r + 1 : r + 1 + a.shape[1]] = a
    return c.cumsum(axis=0).cumsum(axis=1)


class _SmoothedDepth:
    """One view's depth (H, W) float32 (NaN = hole) read at sub-pixel positions: a plane fitted to
    the (2r + 1)^2 window of the nearest pixel when that window is full and its depths scatter less
    than ``edge_std`` metres about the plane (the white part of the sensor noise averages out, and
    the plane's slope corrects for the distance to the pixel centre, up to 1 mm on a slanted
    surface); the raw depth of the nearest pixel elsewhere (depth edges, holes).

    The plane of every pixel's window is fitted once, from integral images (O(1) per pixel), and
    stored as (depth at the pixel centre, slope along u, slope along v); a raw pixel is the plane
    (depth, 0, 0). A read is then one gather of three numbers: the surface estimate reads each
    view 4 times at every candidate voxel, more often than the view has pixels."""

    def __init__(self, z: np.ndarray, size: int, edge_std: float):
        self.z = np.asarray(z, np.float32)
        self.r = max(0, (int(size) - 1) // 2)
        if not self.r:
            return
        h, w = self.z.shape
        k = 2 * self.r + 1
        n = float(k * k)
        ok = np.isfinite(self.z)
        zf = np.where(ok, self.z, 0.0).astype(np.float64)
        rows, cols = np.indices(zf.shape)
        s0, s1, s2, su, sv = (self._box(_box_sums(x, self.r), k, h, w)
                              for x in (ok.astype(np.float64), zf, zf * zf, cols * zf, rows * zf))
        full = s0 > n - 0.5
        mean = s1 / n
        m2 = n * (n - 1.0) / 12.0  # sum of squared offsets along one axis over the window
        gu = (su - cols * s1) / m2
        gv = (sv - rows * s1) / m2
        resid = s2 / n - mean * mean - (gu * gu + gv * gv) * (m2 / n)
        d = self.z.astype(np.float64)
        smooth = full & ok & (resid < float(edge_std) ** 2)
        self.plane = np.stack([np.where(smooth, mean, d), np.where(smooth, gu, 0.0), np.where(smooth, gv, 0.0)],
                              axis=-1).reshape(-1, 3)

    @staticmethod
    def _box(c: np.ndarray, k: int, h: int, w: int) -> np.ndarray:
        """(h, w) sums over the k x k window of every pixel from the padded integral image ``c``."""
        return c[k : k + h, k : k + w] - c[:h, k : k + w] - c[k : k + h, :w] + c[:h, :w]

    def at(self, v: np.ndarray, u: np.ndarray) -> np.ndarray:
        """(M,) float64 depth at sub-pixel positions row ``v``, column ``u`` (M,) whose nearest
        pixel is inside the image."""
        row = np.rint(v).astype(np.intp)
        col = np.rint(u).astype(np.intp)
        flat = row * self.z.shape[1] + col
        if not self.r:
            return np.take(self.z.reshape(-1), flat).astype(np.float64)
        p = np.take(self.plane, flat, axis=0)
        return p[:, 0] + p[:, 1] * (u - col) + p[:, 2] * (v - row)


def smooth_depth(z: np.ndarray, size: int, edge_std: float) -> np.ndarray:
    """(H, W) float32: ``z`` read at every pixel centre as the surface estimate reads it
    (``_SmoothedDepth``: the fitted plane where smooth, the raw depth at edges and holes)."""
    sd = _SmoothedDepth(z, size, edge_std)
    rows, cols = np.indices(sd.z.shape)
    return sd.at(rows.ravel().astype(float), cols.ravel().astype(float)).reshape(sd.z.shape).astype(np.float32)


def snap_to_surface(
    views: Sequence[View],
    points: np.ndarray,
    strides: Sequence[int],
    params: SurfaceParams = SurfaceParams(),
    point_depth: np.ndarray | None = None,
) -> SnappedPoints:
    """Move the raw points of ``views`` onto their multi-view surface (module docstring).

    points: (P, 3) float32 world metres, the back-projected pixels of all views concatenated
    (which view a point came from does not matter: every view is read at every voxel);
    strides: the pixel stride each view was sampled with; point_depth: (P,) metres, each point's
    depth in its own view, for the noise limit of the moves (``SurfaceParams.noise_k``; None = no
    such limit, only ``max_shift``).
    """
    from clutt3r_core.pointcloud import _group_keys, _voxel_keys

    P = np.asarray(points, np.float32)
    n = len(P)
    if n == 0:
        return SnappedPoints(P.copy(), np.zeros(0, bool), np.zeros(0, bool))
    vs = float(params.voxel_size)
    keys, lo, ext = _voxel_keys(P, vs, pad=1)  # an empty layer each side: every 6-neighbour key is valid
    inverse, counts = _group_keys(keys, ext)
    u = int(inverse.max()) + 1
    # keys of each voxel from one of its points (any: they share the key): one scatter, small gathers
    one = np.empty(u, np.intp)
    one[inverse] = np.arange(n)
    ukeys = np.stack([k[one] for k in keys]).astype(np.int64)
    del keys, one
    # voxel centres relative to an origin near the scene (float32 keeps 0.1 um there)
    origin = lo * vs
    centres = ((ukeys.T + 0.5) * vs).astype(np.float32)  # (U, 3), world = origin + centres
    lin = ukeys[0] + ext[0] * (ukeys[1] + ext[1] * ukeys[2])  # ascending (``_group_keys`` order)
    del ukeys

    # ---- projective signed distances of every view at every candidate centre
    sampled = []
    for view, s in zip(views, strides):
        zs = np.asarray(view.depth, np.float32)[::s, ::s]
        zs = np.where((zs >= params.min_depth) & (zs <= params.max_depth), zs, np.float32(np.nan))
        sampled.append((view.camera, s, _SmoothedDepth(zs, params.smooth_px, params.edge_std)))
    D, V, nnear = _distance_field(sampled, centres, origin, params)
    has = nnear > 0

    # ---- gradient of D by central (or one-sided) differences over the 6-neighbours; where neither
    # neighbour along an axis is a candidate (a band one voxel thick: clean depth), D is evaluated
    # one voxel further along that axis
    nbrs = []
    for a, st in enumerate((1, int(ext[0]), int(ext[0] * ext[1]))):
        hits = []
        for sign in (1, -1):
            q = lin + sign * st
            if st == 1:  # keys are sorted and distinct: the x-neighbour, if a candidate, is the next / previous
                j = np.clip(np.arange(u) + sign, 0, u - 1)
            else:
                j = np.searchsorted(lin, q)
                j[j == u] = u - 1
            hits.append((j, (lin[j] == q) & has[j]))  # where not a hit, D[j] is read but not used
        lone = np.flatnonzero(has & ~hits[0][1] & ~hits[1][1])
        step = np.zeros(3, np.float32)
        step[a] = vs
        extra = _distance_field(sampled, centres[lone] + step, origin, params) if len(lone) else None
        nbrs.append((hits, lone, extra))
    g = _gradient(D, nbrs, vs)

    # ---- the same field in metres along the normal: a view's projective distance s_j is
    # 1 / |cos| of the euclidean one, so where the set of views that see a voxel changes (occlusion
    # edges, the border of a view) the mean of s_j jumps and tilts its gradient; -n . mean(s_j r_j)
    # (r_j the unit ray of view j) does not, for any set of views
    def euclid(Vx, nx, gx):
        nrm = np.sqrt((gx * gx).sum(axis=0))
        return np.where((nx > 0) & (nrm > 0), -(gx * Vx).sum(axis=0) / np.maximum(nrm, 1e-12) / np.maximum(nx, 1), 0.0)

    E = euclid(V, nnear, g)
    nbrs_e = []
    for hits, lone, extra in nbrs:
        if extra is not None:
            _, Ve, ne = extra
            extra = (euclid(Ve, ne, g[:, lone]), Ve, ne)
        nbrs_e.append((hits, lone, extra))
    g = _gradient(E, nbrs_e, vs)
    D = E
    g2 = (g * g).sum(axis=0)
    good = has & (g2 > 0.25)  # |g| > 0.5: the ideal is 1
    # D at a point p of voxel k, linearised: D_k + g_k . (p - c_k) = a_k + g_k . p (p relative to origin);
    # the zero crossing along g_k is p - (a_k + g_k . p) g_k / |g_k|^2
    a_k = (D - (g * centres.T).sum(axis=0)).astype(np.float32)
    h = np.where(good, 1.0 / np.where(good, g2, 1.0), 0.0) * g  # g / |g|^2, 0 where not moved
    g32 = g.astype(np.float32)
    h32 = h.astype(np.float32)
    del g, h

    # ---- move every raw point of a good voxel to the zero crossing
    out = np.empty_like(P)
    Pl = [P[:, i] - np.float32(origin[i]) for i in range(3)]
    dist = a_k[inverse]
    for i in range(3):
        dist += g32[i][inverse] * Pl[i]
    moved = good[inverse]
    hn = np.sqrt((h32 * h32).sum(axis=0))[inverse]
    shift = np.abs(dist) * hn
    moved &= shift <= params.max_shift
    sigma = float("nan")
    if params.noise_k > 0 and point_depth is not None and moved.any():
        # the noise in the data: the robust spread of the proposed moves per squared depth (a stereo
        # camera's depth error grows as z^2; on clean depth the spread is the 1 mm quantisation's).
        # Moves far beyond it are the estimate's errors (rim voxels), not the point's noise.
        z2 = np.square(np.asarray(point_depth, np.float32))
        sigma = 1.4826 * float(np.median(shift[moved] / z2[moved]))
        moved &= shift <= np.float32(params.noise_k * sigma) * z2
    dist[~moved] = 0.0
    for i in range(3):
        out[:, i] = Pl[i] - dist * h32[i][inverse] + np.float32(origin[i])
    trusted = moved & (counts >= params.min_points)[inverse]
    return SnappedPoints(out, moved, trusted, sigma)


def _distance_field(sampled, pts: np.ndarray, origin: np.ndarray, params: SurfaceParams):
    """Mean projective signed distance of the views at points (M, 3) float32 (world = origin + pts).

    ``sampled``: per view (camera, stride, ``_SmoothedDepth`` of its sampled grid). Returns
    (D (M,) float64; V (3, M) float64, the sum over those views of s_j times the unit ray of view j;
    the views within +-truncation (M,) int32); D = 0 where no view is within the truncation."""
    m = len(pts)
    T = float(params.truncation)
    ssum = np.zeros(m)
    vsum = np.zeros((3, m))
    nnear = np.zeros(m, np.int32)
    # BLAS takes another path (other rounding) for an F-ordered matrix: z is projected from ``pts`` as
    # given, the image coordinates from a C-ordered copy (one copy for all views)
    pts_c = np.ascontiguousarray(pts)
    for cam, s, depth in sampled:
        h, w = depth.z.shape
        Tcw = cam.T_camera_world
        R = Tcw[:3, :3].astype(np.float32)
        t = (Tcw[:3, :3] @ origin + Tcw[:3, 3]).astype(np.float32)
        z = pts @ R[2] + t[2]
        front = np.flatnonzero(z > params.min_depth)
        if len(front) == m:  # every point in front (the usual case): no gathers
            zf, c = z, pts_c
        else:
            zf, c = z[front], pts_c[front]
        col = ((c @ R[0] + t[0]) * np.float32(cam.fx) / zf + np.float32(cam.cx)) / np.float32(s)
        row = ((c @ R[1] + t[1]) * np.float32(cam.fy) / zf + np.float32(cam.cy)) / np.float32(s)
        inside = np.flatnonzero((col > -0.5) & (col < w - 0.5) & (row > -0.5) & (row < h - 0.5))
        sd = depth.at(row[inside], col[inside]) - zf[inside]
        near = np.flatnonzero(np.abs(sd) <= T)  # NaN (hole) compares False
        sel = inside[near]  # rows of c / front
        i_near = front[sel]
        sdn = sd[near]
        ssum[i_near] += sdn
        # s_j times the unit ray of view j (camera to point), for the euclidean distance; per axis,
        # in the order of a row sum of squares (the same float64 operations as on (N, 3) rows)
        eye = cam.T_world_camera[:3, 3] - origin
        ray = [c[sel, a].astype(np.float64) - eye[a] for a in range(3)]
        f = sdn / np.sqrt((ray[0] * ray[0] + ray[1] * ray[1]) + ray[2] * ray[2])
        for a in range(3):
            vsum[a, i_near] += ray[a] * f
        nnear[i_near] += 1
    return np.divide(ssum, nnear, out=np.zeros(m), where=nnear > 0), vsum, nnear


def _gradient(D: np.ndarray, nbrs, vs: float) -> np.ndarray:
    """(3, U) central (or one-sided) differences of D over the 6-neighbours ``nbrs`` (per axis: the
    (index, hit) of the + and - neighbour, the voxels with neither, and D at one voxel further
    along the axis for those, or None)."""
    g = np.zeros((3, len(D)))
    for a, ((jp, hp), (jm, hm)), lone, extra in ((a, *x) for a, x in enumerate(nbrs)):
        dp, dm = D[jp], D[jm]
        g[a] = np.where(hp & hm, (dp - dm) / (2 * vs),
                        np.where(hp, (dp - D) / vs, np.where(hm, (D - dm) / vs, 0.0)))
        if extra is not None:
            ok = extra[2] > 0
            g[a, lone[ok]] = (extra[0][ok] - D[lone[ok]]) / vs
    return g


@dataclass(frozen=True)
class SurfaceChoice:
    """What the fusion did with the raw points (``surface_points``), for the record.

    Attributes:
        method: ``"voxel-mean"`` (raw points kept) or ``"tsdf"`` (moved onto the surface estimate).
        disagreement: metres, the views' depth disagreement ``DepthAgreement.sigma`` that
            ``surface="auto"`` decided on; NaN when not measured (``surface`` set explicitly).
        move_noise: metres at 1 m, the noise the moves were limited by
            (``SnappedPoints.move_noise``); NaN without the surface estimate.
        rim: rim voxels the fusion set apart (``FusedCloud.rim``); the pipeline labels them after
            the vote and appends them: they are the last ``rim`` points of the ``Segmentation``
            (0 in older traces, and when the rim voxels joined the cloud before segmentation).
    """

    method: str
    disagreement: float = float("nan")
    move_noise: float = float("nan")
    rim: int = 0

    def __post_init__(self) -> None:
        if self.method not in ("voxel-mean", "tsdf"):
            raise SceneError(f"SurfaceChoice.method must be 'voxel-mean' or 'tsdf', got {self.method!r}")
        if int(self.rim) < 0:
            raise SceneError(f"SurfaceChoice.rim must be >= 0, got {self.rim}")
        object.__setattr__(self, "rim", int(self.rim))


def _snap_and_filter(views, P, C, pix_list, offsets, strides, cfg, params):
    """The raw points ``P`` (P, 3) float32 moved onto the surface, with their colours ``C`` (P, 3),
    pixels (``pix_list[v]``: flat pixel indices of view v) and ``offsets`` (V + 1,), less the points
    of voxels that fail the occupancy rule: a voxel of the moved points is kept when it holds
    ``cfg.surface_min_points`` of them or one trusted point (``SnappedPoints.trusted``), or a single
    point that could not be moved and ``cfg.surface_rim_neighbours`` kept neighbours (a *rim* voxel;
    also, when switched on, a single moved point with ``cfg.surface_rim_moved`` kept neighbours, and
    a single unmoved point with a kept voxel within ``cfg.surface_rim_reach``).
    Every kept point's voxel is then kept by the fusion (``min_points`` 1 there). Last: the move
    noise, the (P',) bool rim flag of each kept point (None without rim voxels) and the (P',) int32
    voxel of each kept point, the voxels numbered in the fusion's order (ascending packed key; None
    without points): the fusion groups the same moved points into the same voxels, so it takes
    these instead of grouping them again (ours, issue 13: 0.06 s of CPU on a hard 640x480 8-view
    scene with RealSense-like depth)."""
    from clutt3r_core.pointcloud import _group_keys, _keep_points, _voxel_keys

    if len(P) == 0:  # no depth at all: the fusion reports it
        return P, C, pix_list, offsets, float("nan"), None, None
    # each point's depth in its own view, for the noise limit of the moves
    zp = np.empty(len(P), np.float32)
    for v, view in enumerate(views):
        T = view.camera.T_camera_world
        sl = slice(offsets[v], offsets[v + 1])
        zp[sl] = P[sl] @ T[2, :3].astype(np.float32) + np.float32(T[2, 3])
    sn = snap_to_surface(views, P, strides, params, point_depth=zp)
    del zp
    keys, _, ext = _voxel_keys(sn.points, cfg.voxel_size, pad=1)
    inverse, counts = _group_keys(keys, ext)
    trusted = np.bincount(inverse[sn.trusted], minlength=len(counts)) > 0
    kept = (counts >= cfg.surface_min_points) | trusted
    rim = None
    if cfg.surface_rim_neighbours > 0:
        # a lone point the estimate could not move (a rim: depth edge, grazing view) next to kept voxels
        lone = np.flatnonzero(~kept & (counts == 1))
        lone_moved = np.bincount(inverse[sn.moved], minlength=len(counts))[lone] > 0
        unmoved = lone[~lone_moved]
        nk = _kept_neighbours(keys, ext, inverse, kept, unmoved)
        rim_vox = unmoved[nk >= cfg.surface_rim_neighbours]
        if cfg.surface_rim_reach > 0:
            # a lone unmoved point with no kept neighbour but a kept voxel within the reach
            rim_vox = np.union1d(rim_vox, _near_kept(keys, inverse, kept, unmoved[nk == 0],
                                                     cfg.surface_rim_reach / cfg.voxel_size))
        if cfg.surface_rim_moved > 0:
            # a lone moved point from a voxel of one raw point (the count rule drops it) next to kept voxels
            mv = lone[lone_moved]
            rim_vox = np.union1d(rim_vox, mv[_kept_neighbours(keys, ext, inverse, kept, mv) >= cfg.surface_rim_moved])
        kept[rim_vox] = True
        if len(rim_vox):
            rim = np.zeros(len(counts), bool)
            rim[rim_vox] = True
    del keys
    keep = kept[inverse]
    if rim is not None:
        rim = rim[inverse][keep]  # per kept point; a rim voxel holds exactly one point
    # the kept voxels renumbered in their (key) order: the fusion's grouping of the kept points
    rank = np.cumsum(kept, dtype=np.int32) - np.int32(1)
    vox = np.compress(keep, rank[inverse])
    del rank, inverse
    if keep.all():
        return sn.points, C, pix_list, offsets, sn.move_noise, rim, vox
    return (*_keep_points(sn.points, C, pix_list, offsets, keep), sn.move_noise, rim, vox)


def _near_kept(keys, inverse, kept, cand, reach):
    """The voxels ``cand`` (ascending voxel numbers) with a ``kept`` voxel whose key lies within
    ``reach`` voxel edges (euclidean) of theirs; ``keys``, ``inverse`` as ``_kept_neighbours``."""
    if len(cand) == 0 or not kept.any():
        return cand[:0]
    from clutt3r_core.normals import knn_query, knn_tree

    one = np.empty(len(kept), np.intp)
    one[inverse] = np.arange(len(inverse))
    vk = np.stack([k[one] for k in keys], axis=1).astype(np.float64)
    d2 = knn_query(knn_tree(np.ascontiguousarray(vk[kept])), np.ascontiguousarray(vk[cand]), 1)[0].reshape(-1)
    return cand[d2 <= float(reach) ** 2 + 1e-9]


def _kept_neighbours(keys, ext, inverse, kept, cand):
    """(len(cand),) int: how many of the 26 neighbours of each voxel ``cand`` are ``kept``; ``keys``,
    ``ext``: the points' voxel keys from ``_voxel_keys`` (pad >= 1: every neighbour key is valid),
    ``inverse``: each point's voxel from ``_group_keys`` (voxels ascending by packed key)."""
    if len(cand) == 0 or not kept.any():
        return np.zeros(len(cand), np.int64)
    one = np.empty(len(kept), np.intp)
    one[inverse] = np.arange(len(inverse))
    ex, ey = int(ext[0]), int(ext[1])
    n = _kept_neighbours_grid([k[one] for k in keys], ext, kept, cand)
    if n is not None:
        return n
    lin = keys[0][one].astype(np.int64) + ex * (keys[1][one].astype(np.int64) + ey * keys[2][one].astype(np.int64))
    klin = lin[kept]  # ascending
    q0 = lin[cand]
    n = np.zeros(len(cand), np.int64)
    for dx in (-1, 0, 1):
        for dy in (-1, 0, 1):
            for dz in (-1, 0, 1):
                if dx or dy or dz:
                    q = q0 + (dx + ex * (dy + ey * dz))
                    j = np.minimum(np.searchsorted(klin, q), len(klin) - 1)
                    n += klin[j] == q
    return n


def _kept_neighbours_grid(vkeys, ext, kept, cand):
    """``_kept_neighbours`` by lookups instead of 26 binary searches (ours, issue 13: 0.11 -> 0.06 s
    of CPU on a hard 640x480 8-view scene with RealSense-like depth, 95 k candidates): the kept voxels marked on a two-level dense grid, each
    occupied (x, y) column's rank, then (rank, z); a neighbour is one lookup in each. ``vkeys``: the
    three (U,) int32 keys of every voxel (pad >= 1). The same counts; None when the grids would
    exceed ``pointcloud._DENSE_GRID_CELLS`` cells (the caller then searches)."""
    from clutt3r_core.pointcloud import _DENSE_GRID_CELLS

    ex, ey, ez = (int(e) for e in ext)
    if ex * ey > _DENSE_GRID_CELLS:
        return None
    x, y, z = (np.asarray(k, np.intp) for k in vkeys)
    kx, ky, kz = x[kept], y[kept], z[kept]
    colmark = np.zeros(ex * ey, bool)
    colmark[kx + ex * ky] = True
    cols = np.flatnonzero(colmark)
    del colmark
    if len(cols) * ez > _DENSE_GRID_CELLS:
        return None
    rank = np.full(ex * ey, -1, np.int32)  # -1: no kept voxel in that column; int32: grids < 2^24 cells
    rank[cols] = np.arange(len(cols), dtype=np.int32)
    grid = np.zeros(len(cols) * ez, bool)
    grid[rank[kx + ex * ky] * ez + kz] = True
    qx, qy, qz = x[cand], y[cand], z[cand]
    n = np.zeros(len(cand), np.int64)
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            r = rank[(qx + dx) + ex * (qy + dy)]  # pad >= 1: every neighbour key is on the grid
            has = r >= 0
            base = np.where(has, r, 0) * ez + qz
            for dz in (-1, 0, 1):
                if dx or dy or dz:
                    n += has & grid[base + dz]
    return n


def surface_params(cfg) -> SurfaceParams:
    """The estimate's parameters from a ``pointcloud.PointCloudConfig``."""
    return SurfaceParams(voxel_size=cfg.voxel_size, min_points=cfg.surface_min_points, min_depth=cfg.min_depth,
                         max_depth=cfg.max_depth)


def auto_disagreement(views, strides, cfg) -> float:
    """``surface="auto"``'s measurement: the views' depth disagreement (``depth_agreement``), metres."""
    params = surface_params(cfg)
    return depth_disagreement(views, strides, params.truncation, params.min_depth, params.max_depth).sigma


def surface_points(views, P, C, pix_list, offsets, strides, cfg, sigma=None):
    """The fusion's hook (``pointcloud.fuse_views`` with ``surface`` "tsdf" or "auto").

    ``surface="auto"`` measures the views' depth disagreement (``auto_disagreement``, or ``sigma``
    when the caller measured it already) and runs the surface estimate when it is at least
    ``cfg.surface_auto_sigma``. Returns ``P``, ``C``, ``pix_list`` and ``offsets`` as
    ``_snap_and_filter`` does (unchanged when the estimate does not run), the ``SurfaceChoice``,
    the rim flag of each returned point ((P,) bool, None: no rim voxel) and the voxel of each
    returned point ((P,) int32 in the fusion's voxel order; None when the estimate did not run
    or there are no points: the fusion then groups them itself).
    """
    params = surface_params(cfg)
    if cfg.surface != "auto":
        sigma = float("nan")
    else:
        if sigma is None:
            sigma = auto_disagreement(views, strides, cfg)
        if not sigma >= cfg.surface_auto_sigma:  # NaN (no overlap between views): nothing to agree on
            return P, C, pix_list, offsets, SurfaceChoice("voxel-mean", sigma), None, None
    out = _snap_and_filter(views, P, C, pix_list, offsets, strides, cfg, params)
    return (*out[:4], SurfaceChoice("tsdf", sigma, out[4]), out[5], out[6])
