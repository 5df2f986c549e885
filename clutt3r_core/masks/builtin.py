"""The built-in mask generator: multi-scale RGB-D segmentation with a containment hierarchy.

No weights, no download. One view in, overlapping candidates out, built so that they
behave like Grounded SAM's "object" candidates the method expects (paper Sec. III-A):
under-segmented clusters as parents, objects and parts inside them as children.

Steps (all at a working resolution of at most ``work_width`` pixels wide; masks are
resized back with nearest neighbour):

1. **Support planes.** Depth is back-projected with the view's camera. RANSAC finds the
   dominant plane whose normal is within ``max_plane_tilt_deg`` of world z (world z is up,
   docs/conventions.md); up to ``extra_planes`` further planes parallel to it and
   covering at least ``extra_plane_frac`` of the valid pixels are removed too (a tray floor
   or bin bottom above the table, at most ``max_support_lift`` up). Pixels closer than ``min_height`` to the first plane or
   below it are support.
2. **Coarse regions** (the parents, like Grounded SAM's under-segmented clusters):
   connected components of the remaining pixels, two 4-neighbours joined when their 3D
   distance is below ``coarse_jump_px`` pixel footprints (and at least
   ``coarse_jump_min``).
3. **Superpixels.** Felzenszwalb's graph segmentation on a feature image of CIE Lab colour,
   3D position and normal, intersected with the coarse regions.
4. **Region-adjacency merging.** Adjacent superpixels of one coarse region are merged in
   order of a boundary cost (average linkage over the shared boundary, so one weak
   pixel cannot leak): share of boundary pixel pairs with a depth jump, mean concave
   crease (1 - cos of the normal angle; convex creases count 10 %) across it, and the distance of the regions' mean
   colours. The partition is cut at each of ``levels``: each cut is a partition nested in
   the next, so every candidate's children lie inside it (a containment hierarchy by
   construction).
5. Every distinct region of every level and every coarse region with at least
   ``min_area_frac`` of the image becomes a candidate (a region identical to its parent is
   kept once); regions above ``max_area_frac`` (a wall, the room) are dropped.

Ids are 1..M (the sample layout's 1-based ids). Scores are the cut level at which the
region stops changing, mapped to [0, 1] (higher = more stable), for inspection only.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass

import cv2
import numpy as np
from scipy import sparse
from scipy.sparse.csgraph import connected_components

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import MaskCandidates, View

__all__ = ["BuiltinMaskConfig", "BuiltinMaskGenerator", "builtin_candidates", "SupportPlane", "fit_support_plane"]


@dataclass(frozen=True)
class BuiltinMaskConfig:
    """Settings of the built-in generator (all "ours"; tuned on generated scenes, seeds 100,
    see docs/masks.md for the measurements behind each value).

    Attributes:
        work_width: working resolution, pixels wide (larger views are downscaled; 640 keeps
            a 640x480 view under 1 s on 2 CPU cores).
        ransac_iters: RANSAC hypotheses for the support plane.
        plane_tol: inlier distance to a plane, metres (1 mm depth quantisation plus
            RealSense-like noise at 0.7 m stays well inside 6 mm).
        max_plane_tilt_deg: a support plane's normal is within this angle of world z, degrees.
        extra_planes: further support planes parallel to the first (tray floor, bin bottom).
        extra_plane_frac: an extra plane must hold this fraction of the valid pixels.
        max_support_lift: ...and lie at most this high above the first plane, metres (a tray
            floor is 1-2 cm up; the top of a box lying flat is usually higher).
        min_height: pixels closer than this to the first plane (or below it) are support, metres.
        coarse_jump_px: two neighbour pixels are connected in the coarse step when their 3D
            distance is below this many pixel footprints (depth / focal length)...
        coarse_jump_min: ...and below at least this many metres.
        fine_jump_px: a boundary pixel pair is a depth jump (finer steps) above this many
            pixel footprints.
        fine_jump_min: ...and above at least this many metres.
        normal_window: box filter size for the point map before normals, working pixels.
        superpixel_stride: superpixels are computed every this many working pixels (speed;
            the coarse regions, at full working resolution, still cut them at depth edges).
        felz_scale: Felzenszwalb's scale (larger = bigger superpixels).
        felz_min_size: smallest superpixel, working pixels.
        w_position: weight of 3D position in the feature image, per metre.
        w_normal: weight of the unit normal in the feature image.
        w_jump: weight of the share of boundary pairs with a depth jump in the merge cost.
        w_crease: weight of the mean crease (1 - cos angle of the normals) in the merge cost.
        convex_factor: a convex crease counts this much of a concave one (LCCP's convexity prior).
        w_colour: weight of the mean-colour distance (CIE Lab, /100) in the merge cost.
        levels: merge-cost cuts; one partition per cut, finest first.
        min_area_frac: smallest candidate, fraction of the image (Grounded-SAM-like 4e-4).
        max_area_frac: largest candidate, fraction of the image.
    """

    work_width: int = 640
    ransac_iters: int = 128
    plane_tol: float = 0.006
    max_plane_tilt_deg: float = 35.0
    extra_planes: int = 2
    extra_plane_frac: float = 0.02
    max_support_lift: float = 0.03
    min_height: float = 0.006
    coarse_jump_px: float = 6.0
    coarse_jump_min: float = 0.008
    fine_jump_px: float = 3.0
    fine_jump_min: float = 0.004
    normal_window: int = 5
    superpixel_stride: int = 2
    felz_scale: float = 60.0
    felz_min_size: int = 30
    w_position: float = 400.0
    w_normal: float = 20.0
    w_jump: float = 1.0
    w_crease: float = 2.0
    convex_factor: float = 0.1
    w_colour: float = 0.3
    levels: tuple[float, ...] = (0.5,)
    min_area_frac: float = 4e-4
    max_area_frac: float = 0.3

    def __post_init__(self) -> None:
        if self.work_width < 64:
            raise SceneError(f"work_width must be >= 64 pixels, got {self.work_width}")
        if list(self.levels) != sorted(self.levels) or not self.levels:
            raise SceneError(f"levels must be a non-empty increasing sequence, got {self.levels}")
        if not 0 <= self.min_area_frac < self.max_area_frac <= 1:
            raise SceneError("need 0 <= min_area_frac < max_area_frac <= 1")


@dataclass(frozen=True)
class SupportPlane:
    """A plane n . p + d = 0 in camera coordinates (metres), n unit, oriented so that the
    camera centre has positive height; ``inliers`` (H, W) bool at working resolution."""

    normal: np.ndarray
    offset: float
    inliers: np.ndarray


def _points(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    h, w = depth.shape
    vs, us = np.mgrid[0:h, 0:w].astype(np.float32)
    z = depth.astype(np.float32)
    x = (us - K[0, 2]) / K[0, 0] * z
    y = (vs - K[1, 2]) / K[1, 1] * z
    return np.stack([x, y, z], axis=-1)


def _normals(P: np.ndarray, valid: np.ndarray, win: int) -> tuple[np.ndarray, np.ndarray]:
    """(unit normals, the box-smoothed point map they come from), holes ignored."""
    Pz = np.where(valid[..., None], P, 0).astype(np.float32)
    wsum = cv2.boxFilter(valid.astype(np.float32), -1, (win, win), normalize=False)
    Ps = cv2.boxFilter(Pz, -1, (win, win), normalize=False) / np.maximum(wsum, 1)[..., None]
    du = np.zeros_like(Ps)
    dv = np.zeros_like(Ps)
    du[:, 1:-1] = Ps[:, 2:] - Ps[:, :-2]
    dv[1:-1] = Ps[2:] - Ps[:-2]
    n = np.stack([du[..., 1] * dv[..., 2] - du[..., 2] * dv[..., 1],
                  du[..., 2] * dv[..., 0] - du[..., 0] * dv[..., 2],
                  du[..., 0] * dv[..., 1] - du[..., 1] * dv[..., 0]], axis=-1)  # np.cross is 5x slower
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = n / np.maximum(norm, 1e-12)
    n[n[..., 2] > 0] *= -1  # face the camera (camera looks along +z)
    return n, Ps


def fit_support_plane(
    P: np.ndarray, valid: np.ndarray, up_cam: np.ndarray | None, cfg: BuiltinMaskConfig, rng: np.random.Generator,
    *, parallel_to: np.ndarray | None = None,
) -> SupportPlane | None:
    """RANSAC plane on the valid points; ``up_cam`` (world z in camera coordinates) restricts
    the normal's tilt; ``parallel_to`` restricts it to within 10 degrees of another plane."""
    idx = np.flatnonzero(valid.ravel())
    if len(idx) < 100:
        return None
    pts = P.reshape(-1, 3)[idx].astype(np.float64)
    score_pts = pts[rng.choice(len(pts), size=min(len(pts), 4000), replace=False)]
    tri = rng.integers(0, len(pts), size=(cfg.ransac_iters, 3))
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    n = np.cross(b - a, c - a)
    nn = np.linalg.norm(n, axis=1)
    ok = nn > 1e-9
    n = n[ok] / nn[ok, None]
    a = a[ok]
    cos_max = np.cos(np.deg2rad(cfg.max_plane_tilt_deg))
    ref = parallel_to if parallel_to is not None else up_cam
    if ref is not None:
        lim = np.cos(np.deg2rad(10.0)) if parallel_to is not None else cos_max
        keep = np.abs(n @ ref) >= lim
        n, a = n[keep], a[keep]
    if len(n) == 0:
        return None
    d = -np.sum(n * a, axis=1)
    counts = (np.abs(score_pts @ n.T + d) < cfg.plane_tol).sum(axis=0)
    best = int(np.argmax(counts))
    nb, db = n[best], d[best]
    inl = np.abs(pts @ nb + db) < cfg.plane_tol
    if inl.sum() >= 3:  # least-squares refinement on the inliers
        q = pts[inl]
        cen = q.mean(axis=0)
        _, _, vt = np.linalg.svd(q[rng.choice(len(q), size=min(len(q), 20000), replace=False)] - cen,
                                 full_matrices=False)
        n2 = vt[2]
        if n2 @ nb < 0:
            n2 = -n2
        nb, db = n2, -float(n2 @ cen)
    if db < 0:  # camera centre (origin) above the plane: height = n . p + d > 0 there
        nb, db = -nb, -db
    dist = P.reshape(-1, 3) @ nb + db
    inliers = (np.abs(dist) < cfg.plane_tol).reshape(valid.shape) & valid
    return SupportPlane(nb.astype(np.float64), float(db), inliers)


def _grid_edges(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """All right and down 4-neighbour pixel pairs as flat indices (a, b)."""
    idx = np.arange(h * w).reshape(h, w)
    a = np.concatenate([idx[:, :-1].ravel(), idx[:-1, :].ravel()])
    b = np.concatenate([idx[:, 1:].ravel(), idx[1:, :].ravel()])
    return a, b


def _components(n: int, a: np.ndarray, b: np.ndarray, keep: np.ndarray) -> np.ndarray:
    g = sparse.coo_matrix((np.ones(int(keep.sum()), np.int8), (a[keep], b[keep])), shape=(n, n)).tocsr()
    return connected_components(g, directed=False)[1]


class _UnionFind:
    def __init__(self, n: int) -> None:
        self.p = list(range(n))

    def find(self, x: int) -> int:
        p = self.p
        while p[x] != x:
            p[x] = p[p[x]]
            x = p[x]
        return x


def _merge_levels(
    sp: np.ndarray, n_sp: int, a: np.ndarray, b: np.ndarray, jump: np.ndarray, crease: np.ndarray,
    lab: np.ndarray, cfg: BuiltinMaskConfig,
) -> list[np.ndarray]:
    """Average-linkage merging of superpixels over their shared boundary; returns one
    (n_sp,) region label per level (nested: each level's regions are unions of the previous)."""
    diff = sp[a] != sp[b]
    la, lb = sp[a][diff], sp[b][diff]
    lo, hi = np.minimum(la, lb), np.maximum(la, lb)
    key = lo.astype(np.int64) * n_sp + hi
    uk, inv = np.unique(key, return_inverse=True)
    cnt = np.bincount(inv).astype(np.float64)
    jsum = np.bincount(inv, weights=jump[diff].astype(np.float64))
    csum = np.bincount(inv, weights=crease[diff].astype(np.float64))
    size = np.bincount(sp, minlength=n_sp).astype(np.float64)
    colsum = np.stack([np.bincount(sp, weights=lab[:, k], minlength=n_sp) for k in range(3)], axis=1)
    col = colsum.tolist()
    sz = size.tolist()
    # adjacency: region -> {neighbour: [pairs, jump sum, crease sum]}
    adj: list[dict[int, list[float]]] = [dict() for _ in range(n_sp)]
    for k, u, v, c, j, cr in zip(range(len(uk)), (uk // n_sp).tolist(), (uk % n_sp).tolist(), cnt.tolist(),
                                 jsum.tolist(), csum.tolist()):
        adj[u][v] = [c, j, cr]
        adj[v][u] = adj[u][v]

    def cost(u: int, v: int) -> float:
        c, j, cr = adj[u][v]
        cu, cv_ = col[u], col[v]
        su, sv = max(sz[u], 1.0), max(sz[v], 1.0)
        dc = math.sqrt(sum((cu[k] / su - cv_[k] / sv) ** 2 for k in range(3))) / 100.0
        return cfg.w_jump * j / c + cfg.w_crease * cr / c + cfg.w_colour * dc

    heap = [(cost(u, v), u, v) for u in range(n_sp) for v in adj[u] if u < v]
    heapq.heapify(heap)
    uf = _UnionFind(n_sp)
    alive = [True] * n_sp
    out = []
    for level in cfg.levels:
        while heap and heap[0][0] <= level:
            cst, u, v = heapq.heappop(heap)
            if not (alive[u] and alive[v]) or v not in adj[u]:
                continue
            if abs(cost(u, v) - cst) > 1e-9:  # stale entry (a neighbour merged since)
                continue
            # merge v into u: boundary statistics add up (average linkage over the boundary)
            alive[v] = False
            uf.p[v] = u
            sz[u] += sz[v]
            col[u] = [col[u][k] + col[v][k] for k in range(3)]
            del adj[u][v]
            del adj[v][u]
            for w_, st in adj[v].items():
                del adj[w_][v]
                if w_ in adj[u]:
                    s = adj[u][w_]
                    s[0] += st[0]
                    s[1] += st[1]
                    s[2] += st[2]
                else:
                    adj[u][w_] = list(st)
                    adj[w_][u] = adj[u][w_]
            adj[v] = {}
            for w_ in adj[u]:
                heapq.heappush(heap, (cost(u, w_), min(u, w_), max(u, w_)))
        out.append(np.array([uf.find(i) for i in range(n_sp)], np.int64))
    return out


def builtin_candidates(view: View, cfg: BuiltinMaskConfig = BuiltinMaskConfig(), seed: int = 0) -> MaskCandidates:
    """Candidates of one view (module docstring). Deterministic for a given ``seed``."""
    if view.depth is None:
        raise SceneError(f"{view.name or view.frame}: the built-in mask generator needs depth")
    H, W = view.camera.height, view.camera.width
    rng = np.random.default_rng(seed)
    s = min(1.0, cfg.work_width / W)
    w, h = max(1, round(W * s)), max(1, round(H * s))
    if s < 1.0:
        depth = cv2.resize(view.depth, (w, h), interpolation=cv2.INTER_NEAREST)
        rgb = cv2.resize(view.rgb, (w, h), interpolation=cv2.INTER_AREA)
    else:
        depth, rgb = view.depth, view.rgb
    K = view.camera.K.copy()
    K[:2] *= np.array([[w / W], [h / H]])
    valid = np.isfinite(depth) & (depth > 0)
    P = _points(np.where(valid, depth, 0), K)
    up_cam = view.camera.T_world_camera[:3, :3].T @ np.array([0.0, 0.0, 1.0])

    # 1. support planes
    plane = fit_support_plane(P, valid, up_cam, cfg, rng)
    if plane is None:
        plane = fit_support_plane(P, valid, None, cfg, rng)
    fg = valid.copy()
    if plane is not None:
        height = (P.reshape(-1, 3) @ plane.normal + plane.offset).reshape(h, w)
        fg &= height > cfg.min_height
        rest = fg.copy()
        low = height < cfg.max_support_lift  # a tray floor is low; an object's flat top usually is not
        for _ in range(cfg.extra_planes):
            extra = fit_support_plane(P, rest & low, None, cfg, rng, parallel_to=plane.normal)
            if extra is None or extra.inliers.sum() < cfg.extra_plane_frac * valid.sum():
                break
            rest &= ~extra.inliers
        fg = rest

    # 2. coarse regions: 3D connectivity
    n = h * w
    a, b = _grid_edges(h, w)
    Pf = P.reshape(-1, 3)
    zf = np.where(valid, depth, 0).ravel().astype(np.float32)
    foot = np.maximum(zf[a], zf[b]) / float(K[0, 0])  # metres per pixel at that depth
    d3 = np.linalg.norm(Pf[a] - Pf[b], axis=1)
    fgf = fg.ravel()
    both = fgf[a] & fgf[b]
    coarse_ok = both & (d3 < np.maximum(cfg.coarse_jump_px * foot, cfg.coarse_jump_min))
    comp = _components(n, a, b, coarse_ok)
    comp = np.where(fgf, comp, -1)

    # 3. superpixels on colour + geometry, split by the coarse regions
    lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    lab[..., 0] *= 100.0 / 255.0
    lab[..., 1:] -= 128.0
    nrm, Ps = _normals(P, valid, cfg.normal_window)
    feat = np.concatenate([lab, P * cfg.w_position, nrm * cfg.w_normal], axis=-1)
    feat[~fg] = -1e4  # the support is one far-away colour: no superpixel straddles it
    from skimage.segmentation import felzenszwalb

    st = cfg.superpixel_stride  # Felzenszwalb is the slow step (1.7 s at 640x480, 0.25 s at 320x240)
    small = feat[::st, ::st]
    sp = felzenszwalb(small, scale=cfg.felz_scale, sigma=0.0, min_size=max(1, cfg.felz_min_size // (st * st)),
                      channel_axis=-1)
    sp = np.repeat(np.repeat(sp, st, axis=0), st, axis=1)[:h, :w].ravel()
    key = sp.astype(np.int64) * (n + 1) + (comp + 1)
    _, sp = np.unique(key, return_inverse=True)
    sp = sp.astype(np.int64)
    n_sp = int(sp.max()) + 1

    # 4. merging over the region adjacency graph, only inside a coarse region
    nf = nrm.reshape(-1, 3)
    jump = d3 > np.maximum(cfg.fine_jump_px * foot, cfg.fine_jump_min)
    # concave creases separate objects, convex ones are an object's own edges (the local
    # convexity criterion of LCCP, Stein et al. CVPR 2014): (n_a - n_b) . (p_a - p_b) > 0 is convex
    psf = Ps.reshape(-1, 3)
    convex = np.sum((nf[a] - nf[b]) * (psf[a] - psf[b]), axis=1) > 0
    crease = (1.0 - np.clip(np.sum(nf[a] * nf[b], axis=1), -1, 1)) * np.where(convex, cfg.convex_factor, 1.0)
    inside = coarse_ok  # pairs of one coarse region (never across the support or a jump)
    levels = _merge_levels(sp, n_sp, a[inside], b[inside], jump[inside], crease[inside],
                           lab.reshape(-1, 3).astype(np.float64), cfg)

    # 5. candidates: each level's regions, then the coarse regions; distinct, large enough.
    # Every region is a union of superpixels (they were split by the coarse regions), so
    # regions are compared as superpixel sets and only the kept ones are rasterised.
    sp_area = np.bincount(sp, minlength=n_sp)
    sp_fg = np.bincount(sp, weights=fgf.astype(np.float64), minlength=n_sp) > 0
    sp_comp = np.full(n_sp, -1, np.int64)
    sp_comp[sp] = comp
    min_px = cfg.min_area_frac * h * w
    max_px = cfg.max_area_frac * h * w
    region_labels = [*levels, sp_comp]
    kept: list[np.ndarray] = []
    scores: list[float] = []
    seen: dict[bytes, int] = {}
    for li, lv in enumerate(region_labels):
        lv = np.where(sp_fg, lv, -1)
        order = np.argsort(lv, kind="stable")
        lv_sorted = lv[order]
        starts = np.flatnonzero(np.r_[True, lv_sorted[1:] != lv_sorted[:-1]])
        for members in np.split(order, starts[1:]):
            if lv[members[0]] < 0:
                continue
            area = int(sp_area[members].sum())
            if area < min_px or area > max_px:
                continue
            key_ = np.sort(members).tobytes()
            if key_ in seen:  # unchanged since a finer level: one candidate, more stable
                scores[seen[key_]] = (li + 1) / len(region_labels)
                continue
            seen[key_] = len(kept)
            kept.append(members)
            scores.append((li + 1) / len(region_labels))
    if not kept:
        return MaskCandidates.empty(H, W)
    sp_img = sp.reshape(h, w)
    stack = np.zeros((len(kept), H, W), bool)
    for k, members in enumerate(kept):
        table = np.zeros(n_sp, np.uint8)
        table[members] = 1
        m = table[sp_img]
        if s < 1.0:
            m = cv2.resize(m, (W, H), interpolation=cv2.INTER_NEAREST)
        stack[k] = m > 0
    return MaskCandidates(stack, np.arange(1, len(kept) + 1, dtype=np.int32), np.asarray(scores, np.float32))


class BuiltinMaskGenerator:
    """``MaskGenerator`` ``builtin``: see the module docstring."""

    name = "builtin"

    def __init__(self, config: BuiltinMaskConfig | None = None, seed: int = 0) -> None:
        self.config = config or BuiltinMaskConfig()
        self.seed = seed

    def generate(self, view: View) -> MaskCandidates:
        return builtin_candidates(view, self.config, self.seed)
