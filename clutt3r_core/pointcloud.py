"""Multi-view fusion: back-project posed depth maps into one 5 mm voxel cloud (Sec. III-A, Sec. IV).

Every fused view is back-projected (holes skipped), the points of all views are
concatenated in world coordinates and aggregated on a regular voxel grid. A voxel is
kept when at least ``min_points`` raw points fell in it ("noise-robust voxel
aggregation at 5 mm with a minimum occupancy of m = 3", Sec. IV); it carries the mean
position and colour of its points. The provenance of every sampled pixel is kept
(``FusedCloud.pixel_voxel``) so that 2D masks can later be counted on voxels without
projecting anything again.

Voxel order is the sorted order of the integer voxel keys, so it does not depend on the
order of the views; voxel means do not either (up to float round-off).

(About 640 lines, on purpose: the config, the cloud type and the fusion share these invariants
and are read together; the surface estimate and the rim voxels live in ``surface.py`` and ``rim.py``.)
"""

from __future__ import annotations

import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Literal, Sequence

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.normals import estimate_normals
from clutt3r_core.rim import RimVoxels, rim_apart, split_rim
from clutt3r_core.scene import View

if TYPE_CHECKING:
    from clutt3r_core.surface import SurfaceChoice

__all__ = ["PointCloudConfig", "FusedCloud", "PixelVoxelMaps", "fuse_views", "auto_stride"]

# Image size up to which every pixel is used (the paper's synthetic data, 640x480).
_FULL_RES_PIXELS = 640 * 480


@dataclass(frozen=True)
class PointCloudConfig:
    """Back-projection and voxel aggregation (Sec. III-A preprocessing, Sec. IV)."""

    voxel_size: float = 0.005
    """Voxel edge in metres (Sec. IV, "noise-robust voxel aggregation at 5 mm"; the
    findings measured 10 mm costing 12-26 AP)."""

    min_points: int = 3
    """Raw points a voxel needs to be kept (Sec. IV, minimum occupancy m = 3)."""

    pixel_stride: int = 0
    """Sample every ``pixel_stride``-th pixel in u and v. 0 = automatic (ours, for speed):
    ``auto_stride(H, W) = max(1, round(sqrt(H * W / (640 * 480))))``, i.e. 1 up to 640x480
    and 3 for 1920x1080, which keeps about as many pixels per view as a 640x480 image.
    At 0.5-1 m and 1080p a pixel covers about 0.5 mm, so stride 3 still puts about 9
    samples of every view into each 5 mm voxel; measured on sample_seq4 it loses about
    2% of the voxels (isolated, nearly empty ones at depth edges) against stride 1."""

    min_depth: float = 0.05
    """Nearest depth kept, metres (ours: rejects sensor artefacts on the lens)."""

    max_depth: float = 3.0
    """Farthest depth kept, metres (ours: a tabletop scene is within arm's reach; far
    background and flying pixels beyond are dropped)."""

    normal_knn: int = 20
    """Neighbours for the PCA normal of each voxel (ours; the k of Open3D's
    ``KDTreeSearchParamKNN``, whose estimate ``normals.estimate_normals`` reproduces; 20
    voxels of 5 mm span about a 2 cm disc, enough to average depth noise while keeping
    object edges)."""

    surface: Literal["voxel-mean", "tsdf", "auto"] = "auto"
    """How the raw points of all views become the fused surface. ``voxel-mean`` (Sec. IV): each
    kept voxel is the mean of the raw points in it. ``tsdf`` (ours, issue 13): the raw points are
    first moved onto the views' consensus surface, the zero crossing of a truncated signed
    distance field averaged over the views (``clutt3r_core.surface``), then voxel-averaged.
    ``auto`` (ours): ``tsdf`` when the views' depths disagree by at least ``surface_auto_sigma``
    (measured from the data, ``depth_agreement.depth_disagreement``), else ``voxel-mean``; the fused
    cloud records what was measured and chosen (``FusedCloud.surface``)."""

    surface_auto_sigma: float = 0.001
    """With ``surface="auto"``: the views' depth disagreement (one view's noise, metres) from which
    the surface estimate runs (ours, issue 13). Measured (``depth_agreement.depth_disagreement``): clean
    1 mm-quantised generated depth 0.31-0.32 mm, RealSense-like generated depth 2.4-2.8 mm, the
    real sample_seq1 5.5 mm and sample_seq4 4.0 mm; 1 mm (a fifth of a voxel) lies between with
    a factor of 2.4 to each side. Below it the estimate gains little (docs/benchmark/strict-iou.md)
    and costs about 2.5x the fusion's time."""

    surface_min_points: int = 2
    """With ``surface="tsdf"``: moved points a voxel needs to be kept, or one point moved from a
    voxel of that many raw points (ours, issue 13; replaces ``min_points``, which counts raw
    points spread by the noise). Measured on held-out generated scenes with RealSense-like depth:
    1 and 2 give the same AP (51.4 / 51.1 mean) but 1 keeps 2.5x the voxels of the plain fusion
    (every sparse far-table sample) and 2 keeps 1.2x; 3 lost 6 AP against 1 on the tuning scenes
    (first version of the estimate)."""

    surface_rim_neighbours: int = 1
    """With ``surface="tsdf"``: a voxel whose only point the estimate could not move (object rims) is
    kept as a *rim* voxel when this many of its 26 neighbours are kept; 0 = never (ours, issue 13;
    ``clutt3r_core.rim``; measured in docs/benchmark/strict-iou.md, third pass)."""

    surface_rim_moved: int = 0
    """With ``surface="tsdf"`` and ``surface_rim_neighbours`` on: a voxel holding a single *moved*
    point that came from a voxel of one raw point (the ``surface_min_points`` rule drops it) is kept
    as a rim voxel too when this many of its 26 neighbours are kept; 0 = never (ours, session 9).
    Off: measured on the tuning scenes (docs/benchmark/strict-iou.md, "Session 9: the holes"), 1 / 3
    neighbours: mean AP 53.7 -> 51.9 / 52.4 (5 of 6 scenes lower), holes -15 but off-GT cells +22 per
    scene; these voxels are single-view samples (none of those in hole cells has a second view
    within 2.5 mm), as often beside the surface as on it."""

    surface_rim_reach: float = 0.0
    """With ``surface="tsdf"`` and ``surface_rim_neighbours`` on: a voxel whose only point the estimate
    could not move and that has no kept neighbour is kept as a rim voxel too when a kept voxel's key
    lies within this distance (metres, between voxel keys); 0 = never (ours, session 9).
    Off: measured on the tuning scenes (docs/benchmark/strict-iou.md, "Session 9: the holes"),
    10 / 15 mm: mean AP 53.5 -> 53.3 / 53.2 (holes -2 / -10 per scene, off-GT +1 / +2; hard_0002:
    24 hole cells filled, 20 with the right object, AP unchanged; easy_0003 -1.6); check seeds 0-1
    at 15 mm 55.05 -> 55.48 (no scene lower): about zero over the 12 scenes."""

    surface_rim_attach_k: int = 6
    """Rim voxels are kept apart (``FusedCloud.rim``) and take the majority label of this many nearest
    segmented voxels after the vote (``rim.attach_labels``); 0 = they join the cloud before segmentation
    (ours, issue 13, docs/benchmark/strict-iou.md: joined, hard AP50 93.0 -> 90.3 on the standard
    suite; attached, AP +3.2 / +2.7 on tuning / held-out scenes, AP50 and AP25 never lower)."""

    surface_rim_attach_distance: float = 0.02
    """Metres: segmented voxels farther than this from a rim voxel do not vote (none within: unlabelled).
    Ours: a rim voxel borders a kept voxel, so its nearest lies within two voxel diagonals (17 mm)."""

    def __post_init__(self) -> None:
        if self.surface not in ("voxel-mean", "tsdf", "auto"):
            raise SceneError(f"PointCloudConfig.surface must be 'voxel-mean', 'tsdf' or 'auto', got {self.surface!r}")
        if not self.surface_auto_sigma >= 0:
            raise SceneError(f"PointCloudConfig.surface_auto_sigma must be >= 0, got {self.surface_auto_sigma}")
        if not self.voxel_size > 0:
            raise SceneError(f"PointCloudConfig.voxel_size must be > 0, got {self.voxel_size}")
        if self.min_points < 1:
            raise SceneError(f"PointCloudConfig.min_points must be >= 1, got {self.min_points}")
        if self.pixel_stride < 0:
            raise SceneError(f"PointCloudConfig.pixel_stride must be >= 0 (0 = auto), got {self.pixel_stride}")
        if not 0 <= self.min_depth < self.max_depth:
            raise SceneError(
                f"PointCloudConfig needs 0 <= min_depth < max_depth, got {self.min_depth}, {self.max_depth}"
            )
        if self.surface_rim_neighbours < 0:
            raise SceneError(f"PointCloudConfig.surface_rim_neighbours must be >= 0, got {self.surface_rim_neighbours}")
        if self.surface_rim_attach_k < 0 or not self.surface_rim_attach_distance >= 0:
            raise SceneError("PointCloudConfig.surface_rim_attach_k and surface_rim_attach_distance must be >= 0, "
                             f"got {self.surface_rim_attach_k}, {self.surface_rim_attach_distance}")
        if not self.surface_rim_reach >= 0:
            raise SceneError(f"PointCloudConfig.surface_rim_reach must be >= 0, got {self.surface_rim_reach}")
        if self.surface_rim_moved < 0:
            raise SceneError(f"PointCloudConfig.surface_rim_moved must be >= 0, got {self.surface_rim_moved}")
        if self.surface_min_points < 1:
            raise SceneError(f"PointCloudConfig.surface_min_points must be >= 1, got {self.surface_min_points}")
        if self.normal_knn < 3:
            raise SceneError(f"PointCloudConfig.normal_knn must be >= 3, got {self.normal_knn}")


def auto_stride(height: int, width: int) -> int:
    """The automatic pixel stride: about 640x480 samples per view (see ``PointCloudConfig.pixel_stride``)."""
    return max(1, int(round(math.sqrt(height * width / _FULL_RES_PIXELS))))


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


class PixelVoxelMaps(Sequence):
    """Per view, the (H, W) int32 voxel fed by each pixel (-1 = none), stored sparsely.

    Only the fed pixels are kept: (flat pixel index, voxel) int32 pairs, ascending by pixel.
    At 1080p with the automatic stride 3 a view feeds at most 1/9 of its pixels, so this holds
    8 views in about 15 MiB instead of 66 MiB of dense maps (issue 13: 1080p memory).
    Indexing a view builds its dense read-only map; ``pixels(v)`` gives the pairs without it.
    """

    def __init__(self, pixels: Sequence[tuple[np.ndarray, np.ndarray]], shapes: Sequence[tuple[int, int]]):
        self._pix = tuple(_readonly(np.asarray(p, np.int32)) for p, _ in pixels)
        self._vox = tuple(_readonly(np.asarray(v, np.int32)) for _, v in pixels)
        self.shapes = tuple((int(h), int(w)) for h, w in shapes)

    @classmethod
    def from_dense(cls, maps: Sequence[np.ndarray]) -> "PixelVoxelMaps":
        pairs, shapes = [], []
        for m in maps:
            flat = np.asarray(m).reshape(-1)
            pix = np.flatnonzero(flat >= 0)
            pairs.append((pix, flat[pix]))
            shapes.append(np.shape(m))
        return cls(pairs, shapes)

    def pixels(self, v: int) -> tuple[np.ndarray, np.ndarray]:
        """(flat pixel indices (P,) int32 ascending, voxel (P,) int32) of the pixels of view v that fed a voxel."""
        return self._pix[v], self._vox[v]

    def __len__(self) -> int:
        return len(self.shapes)

    def __getitem__(self, v):  # type: ignore[override]
        if isinstance(v, slice):
            return tuple(self[i] for i in range(*v.indices(len(self))))
        v = range(len(self))[v]  # negative indices, IndexError
        h, w = self.shapes[v]
        out = np.full(h * w, -1, np.int32)
        out[self._pix[v]] = self._vox[v]
        return _readonly(out.reshape(h, w))


@dataclass(frozen=True, eq=False)
class FusedCloud:
    """The fused voxel cloud of a set of views.

    Attributes:
        points: (N, 3) float32 world metres, mean position of the raw points of each voxel.
        colors: (N, 3) uint8 mean RGB of each voxel.
        normals: (N, 3) float32 unit normals (PCA over ``normal_knn`` voxels), oriented
            towards the mean centre of the cameras that saw the voxel.
        counts: (N,) int32 raw points that fell in the voxel (>= min_points).
        voxel_size: voxel edge in metres.
        frames: frame of each fused view, in input order.
        pixel_voxel: per fused view, (H, W) int32 index of the voxel fed by that pixel;
            -1 = none (depth hole or out of range, pixel not on the stride grid, or voxel
            dropped by ``min_points``). Given as dense maps or a ``PixelVoxelMaps``; stored
            as a ``PixelVoxelMaps`` (sparse; ``cloud.pixel_voxel[v]`` is the dense map and
            ``cloud.pixel_voxel.pixels(v)`` the fed pixels and their voxels).
        stride: pixel stride used for each view (ours; 1 = every pixel).
        visibility: (V, N) bool, voxel n was fed by at least one pixel of view v; derived
            from ``pixel_voxel`` when not given.
        camera_centres: (V, 3) float64 world position of each fused view's camera, metres,
            or None when unknown (ours: lets later stages orient things towards the cameras).
        neighbours: (N, k) int32, row n = the k voxels nearest to voxel n by Euclidean
            distance, nearest first (itself included, normally first), equal distances by
            index (``normals.knn_query``); the neighbourhoods of the normals (k =
            ``normal_knn``, or N when smaller), kept so that the super-voxel graph does not
            query them again (ours, issue 13: a second k-NN query was a quarter of the
            super-voxel stage). None when not computed.
        surface: with ``PointCloudConfig.surface`` "tsdf" or "auto", what the fusion measured and
            did (``clutt3r_core.surface.SurfaceChoice``: the views' depth disagreement, the
            method used, the noise that limited the moves); None with "voxel-mean".
        rim: the rim voxels kept apart from this cloud (``clutt3r_core.rim.RimVoxels``; not in
            ``points``, ``pixel_voxel``, ``visibility`` or ``neighbours``, so nothing indexed by
            voxel changes); None when there are none or they joined the cloud.
    """

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    counts: np.ndarray
    voxel_size: float
    frames: tuple[int, ...]
    pixel_voxel: PixelVoxelMaps | Sequence[np.ndarray]
    stride: tuple[int, ...] = ()
    visibility: np.ndarray | None = field(default=None, repr=False)
    camera_centres: np.ndarray | None = field(default=None, repr=False)
    neighbours: np.ndarray | None = field(default=None, repr=False)
    surface: SurfaceChoice | None = None
    rim: RimVoxels | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.rim is not None and not isinstance(self.rim, RimVoxels):
            raise SceneError("FusedCloud.rim must be a clutt3r_core.rim.RimVoxels or None")
        pts = np.asarray(self.points, dtype=np.float32)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise SceneError(f"FusedCloud.points must be (N, 3), got {pts.shape}")
        n = pts.shape[0]
        cols = np.asarray(self.colors)
        if cols.shape != (n, 3) or cols.dtype != np.uint8:
            raise SceneError(f"FusedCloud.colors must be ({n}, 3) uint8, got {cols.dtype} {cols.shape}")
        nrm = np.asarray(self.normals, dtype=np.float32)
        if nrm.shape != (n, 3):
            raise SceneError(f"FusedCloud.normals must be ({n}, 3), got {nrm.shape}")
        cnt = np.asarray(self.counts, dtype=np.int32).reshape(-1)
        if cnt.shape != (n,):
            raise SceneError(f"FusedCloud.counts must be ({n},), got {cnt.shape}")
        if not self.voxel_size > 0:
            raise SceneError(f"FusedCloud.voxel_size must be > 0, got {self.voxel_size}")
        frames = tuple(int(f) for f in self.frames)
        pv = self.pixel_voxel
        if not isinstance(pv, PixelVoxelMaps):
            maps = [np.asarray(p) for p in pv]
            for f, p in zip(frames, maps):
                if p.ndim != 2:
                    raise SceneError(f"FusedCloud.pixel_voxel of frame {f} must be (H, W), got {p.shape}")
                if p.size and p.min() < -1:
                    raise SceneError(f"FusedCloud.pixel_voxel of frame {f} has indices outside -1..{n - 1}")
            pv = PixelVoxelMaps.from_dense(maps)
        if len(pv) != len(frames):
            raise SceneError(f"FusedCloud has {len(frames)} frames but {len(pv)} pixel_voxel maps")
        for v, f in enumerate(frames):
            vox = pv.pixels(v)[1]
            if vox.size and (vox.min() < 0 or vox.max() >= n):
                raise SceneError(f"FusedCloud.pixel_voxel of frame {f} has indices outside -1..{n - 1}")
        stride = tuple(int(s) for s in self.stride) or (1,) * len(frames)
        if len(stride) != len(frames):
            raise SceneError(f"FusedCloud has {len(frames)} frames but {len(stride)} strides")
        vis = self.visibility
        if vis is None:
            vis = np.zeros((len(pv), n), dtype=bool)
            for v in range(len(pv)):
                vis[v, pv.pixels(v)[1]] = True
        else:
            vis = np.asarray(vis, dtype=bool)
            if vis.shape != (len(pv), n):
                raise SceneError(f"FusedCloud.visibility must be ({len(pv)}, {n}), got {vis.shape}")
        if self.camera_centres is not None:
            cc = np.asarray(self.camera_centres, dtype=np.float64)
            if cc.shape != (len(pv), 3):
                raise SceneError(f"FusedCloud.camera_centres must be ({len(pv)}, 3), got {cc.shape}")
            object.__setattr__(self, "camera_centres", _readonly(cc))
        if self.neighbours is not None:
            nb = np.asarray(self.neighbours)
            if nb.ndim != 2 or nb.shape[0] != n or nb.dtype.kind not in "iu":
                raise SceneError(f"FusedCloud.neighbours must be ({n}, k) integers, got {nb.dtype} {nb.shape}")
            if nb.size and (nb.min() < 0 or nb.max() >= n):
                raise SceneError(f"FusedCloud.neighbours has indices outside 0..{n - 1}")
            object.__setattr__(self, "neighbours", _readonly(nb.astype(np.int32, copy=False)))
        object.__setattr__(self, "points", _readonly(pts))
        object.__setattr__(self, "colors", _readonly(cols))
        object.__setattr__(self, "normals", _readonly(nrm))
        object.__setattr__(self, "counts", _readonly(cnt))
        object.__setattr__(self, "voxel_size", float(self.voxel_size))
        object.__setattr__(self, "frames", frames)
        object.__setattr__(self, "pixel_voxel", pv)
        object.__setattr__(self, "stride", stride)
        object.__setattr__(self, "visibility", _readonly(vis))

    @property
    def num(self) -> int:
        """Number of voxels N."""
        return int(self.points.shape[0])

    def visible(self) -> np.ndarray:
        """(V, N) bool: voxel n was fed by at least one pixel of view v."""
        return self.visibility

    def view_index(self, frame: int) -> int:
        """Index into ``frames`` / ``pixel_voxel`` of a frame number."""
        try:
            return self.frames.index(int(frame))
        except ValueError:
            raise KeyError(f"frame {frame} is not in the fused cloud (frames {list(self.frames)})") from None


def _backproject_strided(view: View, stride: int, cfg: PointCloudConfig) -> tuple[np.ndarray, np.ndarray]:
    """Back-project the valid pixels of ``view`` on a ``stride`` grid.

    Same geometry as ``Camera.backproject`` (which the tests compare against), but in
    float32 and on a strided view of the depth map, because this is the hot loop of the
    pipeline (16.6 M pixels for 8 views at 1080p). Returns (points (P, 3) float32 world
    metres, flat full-resolution pixel indices (P,) int64, row-major).
    """
    cam = view.camera
    z = view.depth[::stride, ::stride]
    ok = (z >= cfg.min_depth) & (z <= cfg.max_depth)  # NaN holes compare False
    hs, ws = z.shape
    zf = z if z.dtype == np.float32 else z.astype(np.float32)
    # (u - cx) / fx once per column and (v - cy) / fy once per row, times the depth on the
    # whole strided grid, then the valid pixels picked: the same float32 operations in the
    # same order as per pixel, without gathering per-pixel u, v (0.6x the CPU, issue 13)
    xt = (np.arange(0, ws * stride, stride).astype(np.float32) - np.float32(cam.cx)) * np.float32(1.0 / cam.fx)
    yt = (np.arange(0, hs * stride, stride).astype(np.float32) - np.float32(cam.cy)) * np.float32(1.0 / cam.fy)
    zs = zf[ok]
    with np.errstate(invalid="ignore", over="ignore"):  # holes and out-of-range depth are dropped
        x = (xt[None, :] * zf)[ok]
        y = (yt[:, None] * zf)[ok]
    T = cam.T_world_camera.astype(np.float32)
    n = len(zs)
    pw = np.empty((n, 3), np.float32)
    acc, tmp = np.empty(n, np.float32), np.empty(n, np.float32)
    for a in range(3):  # T[a, 0] x + T[a, 1] y + T[a, 2] z + T[a, 3], in place, left to right
        np.multiply(x, T[a, 0], out=acc)
        np.multiply(y, T[a, 1], out=tmp)
        acc += tmp
        np.multiply(zs, T[a, 2], out=tmp)
        acc += tmp
        acc += T[a, 3]
        pw[:, a] = acc
    if stride == 1 and ws == cam.width:
        return pw, np.flatnonzero(ok)
    pix = (np.arange(hs, dtype=np.int64) * (stride * cam.width))[:, None] + np.arange(0, ws * stride, stride)
    return pw, pix[ok]


# Largest dense grid indexed directly (ours: 2^24 cells = 16 MB of bool marks plus
# 64 MB of int32 lookup); bigger scenes fall back to sorting the voxel keys.
_DENSE_GRID_CELLS = 1 << 24


def _compact(lin: np.ndarray, ncells: int) -> tuple[np.ndarray, int]:
    """Rank of each key among the distinct keys of ``lin`` (values in 0..ncells-1), by
    marking a dense bool grid: O(P + cells), no sort. Returns ((P,) int32, distinct count)."""
    lin = lin.astype(np.intp)  # fancy indexing casts int32 indices on every use: once (issue 13)
    occ = np.zeros(ncells, dtype=bool)
    occ[lin] = True
    occupied = np.flatnonzero(occ)
    del occ
    lut = np.empty(ncells, dtype=np.int32)
    lut[occupied] = np.arange(len(occupied), dtype=np.int32)
    return np.take(lut, lin), len(occupied)  # np.take: lut[lin], a little faster (session 6)


def _voxel_keys(P: np.ndarray, voxel_size: float, pad: int = 0) -> tuple[list[np.ndarray], np.ndarray, np.ndarray]:
    """Integer voxel keys of (P, 3) float32 points (P > 0): three (P,) int32 columns, the lowest
    occupied voxel at ``pad`` (``pad`` empty layers below, so every neighbour key is >= 0), the
    lower corner (3,) float in voxels (key 0) and the extent (3,) int64 with ``pad`` empty layers
    above. ``SceneError`` when the points span too many voxels to index."""
    # One contiguous column at a time: reductions along axis 0 of a (P, 3) array are slow.
    inv_size = np.float32(1.0 / voxel_size)
    keys, lows = [], []
    for a in range(3):
        k = np.floor(P[:, a] * inv_size)  # float32; exact integers below 2^24
        lo, hi = float(k.min()), float(k.max())
        if hi - lo >= 2**24:  # 84 km at 5 mm: no tabletop; also keeps the keys exact int32
            raise SceneError(f"fused scene spans {hi - lo + 1:.0f} voxels along axis {a}, too large to "
                             "index (check depth and poses)")
        k -= np.float32(lo - pad)
        keys.append(k.astype(np.int32))
        lows.append(lo - pad)
        del k
    ext = np.array([int(k.max()) + 1 + pad for k in keys], dtype=np.int64)
    if float(np.prod(ext.astype(np.float64))) >= 2.0**62:
        raise SceneError(f"fused scene spans {ext.tolist()} voxels, too large to index (check depth and poses)")
    return keys, np.asarray(lows), ext


def _group_keys(keys: list[np.ndarray], ext: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group integer voxel keys (three (P,) int32 columns in 0..ext-1).

    Returns (inverse (P,) int32 into the distinct voxels, counts (U,) int64), voxels in
    the sorted order of the packed key x + ex * (y + ey * z), as np.unique would give.
    Two dense passes over a pair of axes, then the pair's rank and the third axis: (x, y)
    columns then (column, z), or (y, z) rows then (x, row); both ranks are that (z, y, x)
    order. The pair with the smaller grid goes first (ours, session 6): the second pass's grid
    is then usually smaller too (hard 640x480 seed 0, whose far floor spans 6 x 6 m: 5.9 M
    cells instead of 15.3 M, 0.060 vs 0.078 s of CPU; the real samples within 2 ms).
    """
    ex, ey, ez = (int(e) for e in ext)
    # int32 arithmetic is exact below: every packed key stays below _DENSE_GRID_CELLS
    rows_first = ey * ez < ex * ey
    if rows_first and ey * ez <= _DENSE_GRID_CELLS:
        row, nrow = _compact(keys[1] + np.int32(ey) * keys[2], ey * ez)
        if nrow * ex <= _DENSE_GRID_CELLS:
            row *= np.int32(ex)
            row += keys[0]
            inverse, u = _compact(row, nrow * ex)
            return inverse, np.bincount(inverse, minlength=u)
        del row
    if ex * ey <= _DENSE_GRID_CELLS:  # columns first (or the rows' second grid was too large)
        col, ncol = _compact(keys[0] + np.int32(ex) * keys[1], ex * ey)
        if ncol * ez <= _DENSE_GRID_CELLS:
            col += np.int32(ncol) * keys[2]
            inverse, u = _compact(col, ncol * ez)
            return inverse, np.bincount(inverse, minlength=u)
        del col
    lin = keys[0].astype(np.int64) + ex * (keys[1].astype(np.int64) + ey * keys[2].astype(np.int64))
    _, inverse, counts = np.unique(lin, return_inverse=True, return_counts=True)
    return inverse.reshape(-1).astype(np.int32), counts


def _keep_points(P, C, pix_list, offsets, keep):
    """The fusion's raw points ``P`` (P, 3), colours ``C`` (P, 3), per-view flat pixel indices
    ``pix_list`` and ``offsets`` (V + 1,) with only the points where ``keep`` (P,) bool is true
    (the surface estimate's occupancy rule, the rim voxels set apart)."""
    pix_list = [pix[keep[offsets[v] : offsets[v + 1]]] for v, pix in enumerate(pix_list)]
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in pix_list])])
    # np.compress: the rows a boolean index picks, about 4x faster on (P, 3) arrays (issue 13)
    return np.compress(keep, P, axis=0), np.compress(keep, C, axis=0), pix_list, offsets


def _voxel_sums(vox: np.ndarray, X: np.ndarray, n: int) -> np.ndarray:
    """(n, 3) float64 sums of the columns of ``X`` (P, 3) per voxel ``vox`` (P,) intp (bin n:
    dropped points, cut off)."""
    return np.stack([np.bincount(vox, weights=X[:, a], minlength=n + 1)[:n] for a in range(3)], axis=1)


# Bits per channel of the packed colour sums (_colour_sums): 255 x 514 < 2^17, and three fields
# (51 bits) stay below float64's 53-bit integers.
_COLOUR_FIELD = 17
_COLOUR_PACK_MAX_COUNT = ((1 << _COLOUR_FIELD) - 1) // 255


def _colour_sums(vox: np.ndarray, C: np.ndarray, n: int, max_count: int) -> np.ndarray:
    """(n, 3) float64 sums of the uint8 colours ``C`` (P, 3) per voxel ``vox`` (P,) intp (bin n:
    dropped points), ``max_count`` the most points of a kept voxel.

    Integer sums, so any summation is exact: below ``_COLOUR_PACK_MAX_COUNT`` points per voxel the
    three channels are packed into one float64 weight (r + g 2^17 + b 2^34) and summed by one
    ``bincount`` instead of three (ours, issue 13: 25 vs 34 ms of CPU for 2.4 M points); the
    same values as summing each channel.
    """
    if max_count > _COLOUR_PACK_MAX_COUNT:
        return _voxel_sums(vox, C, n)
    f = _COLOUR_FIELD
    w = C[:, 0] + C[:, 1] * float(1 << f) + C[:, 2] * float(1 << 2 * f)
    # the dropped points' bin n may hold more than the fields allow: it is cut off unread
    packed = np.bincount(vox, weights=w, minlength=n + 1)[:n].astype(np.int64)
    del w
    field = (1 << f) - 1
    return np.stack([packed & field, (packed >> f) & field, packed >> 2 * f], axis=1).astype(np.float64)


def fuse_views(views: Sequence[View], cfg: PointCloudConfig = PointCloudConfig()) -> FusedCloud:
    """Back-project and fuse ``views`` into one voxel cloud (Sec. III-A, Sec. IV).

    Works on sensor depth (holes = NaN) and dense predicted depth alike. Points outside
    [min_depth, max_depth] are dropped. Raises SceneError for a view without depth.
    Auto's depth disagreement and the voxel position sums run on a second thread beside the
    rest (issue 13: the calling thread's share of the core); the results do not depend on it.
    """
    views = list(views)
    if not views:
        raise SceneError("fuse_views needs at least one view")
    for view in views:
        if view.depth is None:
            raise SceneError(f"{view.name or f'frame {view.frame}'}: cannot fuse a view without depth")
    strides = [cfg.pixel_stride or auto_stride(v.camera.height, v.camera.width) for v in views]
    # ours (issue 13): a second thread for work that needs only what is known already; the same
    # calls on the same inputs, so the same results. Leaving the block (after an error too) waits
    # for the thread's work, which an error then drops.
    with ThreadPoolExecutor(1) as pool:
        sigma = None
        if cfg.surface == "auto":
            # "auto"'s depth disagreement needs only the views: measured while they are back-projected
            from clutt3r_core.surface import auto_disagreement

            sigma = pool.submit(auto_disagreement, views, strides, cfg)
        return _fuse(views, strides, cfg, pool, sigma)


def _fuse(views: list[View], strides: list[int], cfg: PointCloudConfig, pool: ThreadPoolExecutor,
          sigma: Future | None) -> FusedCloud:
    """``fuse_views`` of checked views at their pixel strides, with a one-thread ``pool`` for
    work beside it; ``sigma``: a future of ``surface.auto_disagreement`` with ``surface="auto"``,
    else None."""
    pts_list, col_list, pix_list = [], [], []
    for view, s in zip(views, strides):
        pw, pix = _backproject_strided(view, s, cfg)
        pts_list.append(pw)
        col_list.append(np.take(view.rgb.reshape(-1, 3), pix, axis=0))
        pix_list.append(pix)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in pix_list])])
    # Memory (issue 13: 1080p): the per-view lists are freed as soon as they are joined, keys
    # and voxel indices are int32, and the raw points go before the normals are estimated.
    P = np.concatenate(pts_list)
    pts_list.clear()
    C = np.concatenate(col_list)
    col_list.clear()
    min_points = cfg.min_points
    surface = rim_pc = grouped = None
    if cfg.surface != "voxel-mean":  # ours (issue 13): raw points moved onto the views' consensus surface
        from clutt3r_core.surface import surface_points

        # it drops the points of voxels that fail its own occupancy rule (clutt3r_core.surface), and
        # gives the voxel of each point it returns (it grouped them)
        sig = sigma.result() if sigma is not None else None  # re-raises the thread's error
        P, C, pix_list, offsets, surface, rim, grouped = surface_points(views, P, C, pix_list, offsets, strides, cfg,
                                                                         sigma=sig)
        if surface.method == "tsdf":
            min_points = 1
        if rim is not None and cfg.surface_rim_attach_k > 0:
            # rim voxels apart: the cloud below is the one without them (clutt3r_core.rim)
            P, C, pix_list, offsets, rim_pc = split_rim(P, C, pix_list, offsets, rim)
            if grouped is not None:
                grouped = np.compress(~rim, grouped)
        del rim

    # Integer voxel keys packed into one int64, then grouped.
    if len(P) and grouped is not None:
        # the surface estimate's voxels of these points (the same keys, so the same voxels in the
        # same order), renumbered without those left empty (rim voxels set apart)
        counts = np.bincount(grouped)
        present = counts > 0
        inverse = (np.cumsum(present, dtype=np.int32) - np.int32(1))[grouped]
        counts = counts[present]
        del grouped, present
    elif len(P):
        keys, _, ext = _voxel_keys(P, cfg.voxel_size)
        inverse, counts = _group_keys(keys, ext)
        del keys
    else:
        inverse = np.zeros(0, np.int64)
        counts = np.zeros(0, np.int64)
    keep = counts >= min_points
    n = int(keep.sum())
    # Dropped voxels map to a trash bin n, so the sums below need no masking.
    remap = np.full(len(counts), n, dtype=np.int32)
    remap[keep] = np.arange(n, dtype=np.int32)
    vox = np.take(remap, inverse)  # (P,) kept voxel of every raw point, n = dropped
    del inverse, remap
    cnt = counts[keep]
    denom = np.maximum(cnt, 1)[:, None]
    # np.bincount casts int32 bins to intp on every call: once here for the six sums (issue 13)
    vox_p = vox.astype(np.intp)
    # the positions' sums on the second thread while the colours' and the pixel maps are made here
    mean = pool.submit(lambda: _voxel_sums(vox_p, P, n) / denom)
    cmean = _colour_sums(vox_p, C, n, int(cnt.max()) if n else 0) / denom

    pixel_pairs = []
    vis = np.zeros((len(views), n + 1), dtype=bool)
    for i, view in enumerate(views):
        vv = vox[offsets[i] : offsets[i + 1]]
        fed = vv < n
        # pixels ascend (row-major strided grid), as PixelVoxelMaps expects
        # int32 now (PixelVoxelMaps stores them so): int64 pairs were live during the normals
        pixel_pairs.append((pix_list[i][fed].astype(np.int32), vv[fed]))
        vis[i, vv] = True
        pix_list[i] = None
    del vox
    vis = vis[:, :n]
    mean = mean.result()  # re-raises the thread's error
    del vox_p, P, C

    normals, neighbours = estimate_normals(mean, cfg.normal_knn, neighbours=True)
    centres = np.stack([v.camera.T_world_camera[:3, 3] for v in views])
    if n:
        # Orient each normal towards the mean centre of the cameras that observed the voxel.
        nvis = vis.sum(axis=0)
        cam_mean = (vis.T.astype(np.float64) @ centres) / np.maximum(nvis, 1)[:, None]
        flip = np.einsum("ij,ij->i", normals, cam_mean - mean) < 0
        normals[flip] *= -1.0
    rim_voxels = rim_apart(*rim_pc, mean, normals) if rim_pc is not None else None
    if rim_voxels is not None:
        surface = replace(surface, rim=rim_voxels.num)

    return FusedCloud(
        points=mean.astype(np.float32),
        colors=np.clip(np.rint(cmean), 0, 255).astype(np.uint8),
        normals=normals.astype(np.float32),
        counts=cnt.astype(np.int32),
        voxel_size=cfg.voxel_size,
        frames=tuple(v.frame for v in views),
        pixel_voxel=PixelVoxelMaps(pixel_pairs, [(v.camera.height, v.camera.width) for v in views]),
        stride=tuple(strides),
        visibility=vis,
        camera_centres=centres,
        neighbours=neighbours,
        surface=surface,
        rim=rim_voxels,
    )
