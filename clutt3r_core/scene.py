"""The scene model: cameras, views, mask candidates, ground truth.

Every type here is a frozen dataclass of numpy arrays, validated on construction
(shape, dtype, units). Conventions (docs/conventions.md): OpenCV camera axes
(x right, y down, z forward), ``T_world_camera`` maps camera coordinates to world
coordinates, metres, world z up, image coordinates (u, v) = (column, row).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import Iterable

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.mask_codes import encode_masks, small_codes

__all__ = [
    "Camera",
    "MaskCandidates",
    "View",
    "ObjectInfo",
    "GroundTruth",
    "Scene",
    "check_rigid",
]

_RIGID_TOL = 1e-3


def check_rigid(T: np.ndarray, what: str) -> np.ndarray:
    """Return ``T`` as float64 (4, 4) or raise SceneError naming ``what``.

    A rigid transform has an orthonormal rotation block with determinant +1 and a
    last row (0, 0, 0, 1). The tolerance (1e-3) admits float32 round-off in files.
    """
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise SceneError(f"{what}: transform must be 4x4, got shape {T.shape}")
    if not np.all(np.isfinite(T)):
        raise SceneError(f"{what}: transform contains NaN or inf")
    if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=_RIGID_TOL):
        raise SceneError(f"{what}: last row of the transform must be [0, 0, 0, 1], got {T[3].tolist()}")
    R = T[:3, :3]
    err = np.abs(R.T @ R - np.eye(3)).max()
    det = np.linalg.det(R)
    if err <= _RIGID_TOL and det < 0:
        raise SceneError(f"{what}: transform is not rigid: it is a reflection (det {det:.3g}); mirrored poses are not supported")
    if err > _RIGID_TOL:
        raise SceneError(
            f"{what}: transform is not rigid (rotation not orthonormal, max |R^T R - I| = {err:.3g},"
            f" det = {np.linalg.det(R):.3g}); scaled or sheared poses are not supported"
        )
    return T


def _frozen_array(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class Camera:
    """A pinhole camera.

    Attributes:
        K: (3, 3) float64 intrinsics in pixels; u = fx * x / z + cx (column), v = fy * y / z + cy (row).
        width: image width in pixels.
        height: image height in pixels.
        T_world_camera: (4, 4) float64 rigid camera-to-world transform, OpenCV axes, metres.
    """

    K: np.ndarray
    width: int
    height: int
    T_world_camera: np.ndarray

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=np.float64)
        if K.shape != (3, 3):
            raise SceneError(f"camera intrinsics K must be 3x3, got shape {K.shape}")
        if not (K[0, 0] > 0 and K[1, 1] > 0) or not np.allclose(K[2], [0, 0, 1]):
            raise SceneError(f"camera intrinsics K must have fx, fy > 0 and last row [0, 0, 1], got {K.tolist()}")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise SceneError(f"camera size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", _frozen_array(K))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "T_world_camera", _frozen_array(check_rigid(self.T_world_camera, "camera pose")))

    def to_json(self) -> dict:
        """``{"K", "width", "height", "T_world_camera"}`` (lists; a camera file ``clutt3r update
        --camera`` reads, ``update.inputs.read_camera_json``; floats round-trip exactly)."""
        return {"K": self.K.tolist(), "width": self.width, "height": self.height,
                "T_world_camera": self.T_world_camera.tolist()}

    @staticmethod
    def from_json(d: dict) -> "Camera":
        """The camera of ``to_json``'s dict; ``KeyError`` naming a missing field, ``SceneError``
        when it is not a valid camera."""
        return Camera(np.asarray(d["K"], float), int(d["width"]), int(d["height"]),
                      np.asarray(d["T_world_camera"], float))

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @cached_property
    def T_camera_world(self) -> np.ndarray:
        """(4, 4) world-to-camera transform (the inverse of ``T_world_camera``), read-only:
        computed once per camera (the update's pose fit projects into one camera hundreds of times)."""
        R = self.T_world_camera[:3, :3]
        t = self.T_world_camera[:3, 3]
        T = np.eye(4)
        T[:3, :3] = R.T
        T[:3, 3] = -R.T @ t
        return _frozen_array(T)

    def project(self, points_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project (N, 3) world points. Returns (uv (N, 2) float64 pixels, z (N,) metres)."""
        p = np.asarray(points_world, dtype=np.float64).reshape(-1, 3)
        T = self.T_camera_world
        pc = p @ T[:3, :3].T + T[:3, 3]
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            u = self.fx * pc[:, 0] / z + self.cx
            v = self.fy * pc[:, 1] / z + self.cy
        return np.stack([u, v], axis=1), z

    def backproject(self, depth: np.ndarray, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """Back-project a (H, W) depth map (metres, NaN or 0 = hole) to world points.

        Returns (points (N, 3) float64 world metres, flat pixel indices (N,) int64 into
        the full-resolution image, row-major) for the valid pixels on a ``stride`` grid.
        """
        depth = np.asarray(depth)
        if depth.shape != (self.height, self.width):
            raise SceneError(f"depth shape {depth.shape} does not match camera {self.height}x{self.width}")
        vs, us = np.mgrid[0 : self.height : stride, 0 : self.width : stride]
        z = depth[vs, us]
        ok = np.isfinite(z) & (z > 0)
        us, vs = us[ok], vs[ok]
        return self.pixels_to_world(us, vs, z[ok]), (vs.astype(np.int64) * self.width + us.astype(np.int64))

    def pixels_to_world(self, us: np.ndarray, vs: np.ndarray, z: np.ndarray) -> np.ndarray:
        """(N, 3) float64 world points of pixels (column ``us``, row ``vs``) at depths ``z`` (metres)."""
        z = np.asarray(z, dtype=np.float64)
        x = (us - self.cx) / self.fx * z
        y = (vs - self.cy) / self.fy * z
        pc = np.stack([x, y, z], axis=1)
        T = self.T_world_camera
        return pc @ T[:3, :3].T + T[:3, 3]


@dataclass(frozen=True, eq=False, init=False)
class MaskCandidates:
    """The noisy, overlapping mask candidates of one view (e.g. Grounded SAM, prompt "object").

    Stored compactly (issue 13: the (M, H, W) bool stacks of a 1080p scene were 240 MiB, most
    of the command's peak memory): every pixel carries the index of the set of masks that
    contain it (``codes``), and a small table says which masks each set holds (``bits``).
    Overlapping and nested candidates form a few hundred distinct sets, so a 1080p view
    costs one 2-4 MiB code image instead of 2 MiB per mask, and per-mask pixel sums (areas,
    pairwise overlaps, histograms, hits per voxel) are sums over the sets, exact for counts.

    Build from a stack, ``MaskCandidates(masks, ids, scores)`` (as before), from masks
    decoded one at a time (``MaskCandidates.from_masks``: the loaders), or from codes.

    Attributes:
        codes: (H, W) uint8 / uint16 / int32 set index of every pixel, 0..C-1.
        bits: (C, M) bool: set c contains mask m. M may be 0.
        ids: (M,) int32 candidate ids, unique within the view (the ``MM`` of
            ``mask_FFFFFF_MM.png``; 1-based in the sample layout).
        scores: optional (M,) float32 detector confidences in [0, 1].

    ``masks`` gives the (M, H, W) bool stack of the older API: materialised on first use
    and kept (costly: M x H x W bytes; 30 MiB for 15 masks at 1080p). Code that needs a few
    masks should use ``mask(i)`` or ``stack(idx)``, which keep nothing.
    """

    codes: np.ndarray
    bits: np.ndarray
    ids: np.ndarray
    scores: np.ndarray | None = None

    def __init__(self, masks: np.ndarray | None = None, ids: np.ndarray | None = None,
                 scores: np.ndarray | None = None, *, codes: np.ndarray | None = None,
                 bits: np.ndarray | None = None) -> None:
        if (masks is None) == (codes is None):
            raise SceneError("MaskCandidates needs either a (M, H, W) mask stack or codes and bits")
        if ids is None:
            raise SceneError("MaskCandidates needs ids, one per mask")
        ids = np.asarray(ids, dtype=np.int32).reshape(-1)
        if masks is not None:
            masks = np.asarray(masks)
            if masks.ndim != 3:
                raise SceneError(f"mask stack must be (M, H, W), got shape {masks.shape}")
            if ids.shape[0] != masks.shape[0]:
                raise SceneError(f"{masks.shape[0]} masks but {ids.shape[0]} ids")
            label, bits = encode_masks(masks.astype(bool, copy=False), masks.shape[1] * masks.shape[2])
            codes = small_codes(label, len(bits), masks.shape[1:])
        else:
            codes = np.asarray(codes)
            bits = np.asarray(bits, dtype=bool)
            if codes.ndim != 2 or codes.dtype.kind not in "iu":
                raise SceneError(f"mask codes must be an (H, W) integer image, got {codes.dtype} {codes.shape}")
            if bits.ndim != 2 or bits.shape[0] < 1:
                raise SceneError(f"mask bits must be (C >= 1, M), got shape {bits.shape}")
            if codes.size and (codes.min() < 0 or codes.max() >= bits.shape[0]):
                raise SceneError(f"mask codes must lie in 0..{bits.shape[0] - 1}")
            if ids.shape[0] != bits.shape[1]:
                raise SceneError(f"{bits.shape[1]} masks but {ids.shape[0]} ids")
        if len(np.unique(ids)) != len(ids):
            raise SceneError(f"mask ids must be unique within a view, got {ids.tolist()}")
        object.__setattr__(self, "codes", _frozen_array(codes))
        object.__setattr__(self, "bits", _frozen_array(bits))
        object.__setattr__(self, "ids", _frozen_array(ids))
        if scores is not None:
            s = np.asarray(scores, dtype=np.float32).reshape(-1)
            if s.shape != ids.shape:
                raise SceneError(f"mask scores shape {s.shape} does not match {ids.shape[0]} masks")
            scores = _frozen_array(s)
        object.__setattr__(self, "scores", scores)

    @staticmethod
    def from_masks(masks: Iterable[np.ndarray], ids: np.ndarray, shape: tuple[int, int],
                   scores: np.ndarray | None = None) -> "MaskCandidates":
        """From (H, W) bool masks given one at a time (a generator: only one is held at once)."""
        h, w = int(shape[0]), int(shape[1])
        label, bits = encode_masks(masks, h * w)
        return MaskCandidates(ids=ids, scores=scores, codes=small_codes(label, len(bits), (h, w)), bits=bits)

    def __len__(self) -> int:
        return int(self.bits.shape[1])

    @property
    def shape(self) -> tuple[int, int]:
        return int(self.codes.shape[0]), int(self.codes.shape[1])

    def set_counts(self) -> np.ndarray:
        """(C,) int64 pixels per set of masks."""
        c, flat = len(self.bits), self.codes.reshape(-1)
        if self.codes.dtype in (np.uint8, np.uint16) and flat.size < 1 << 24:
            import cv2  # an 8/16-bit histogram without np.bincount's int64 copy; float32 counts exact below 2^24

            return cv2.calcHist([flat], [0], None, [c], [0, c]).reshape(-1).astype(np.int64)
        return np.bincount(flat, minlength=c).astype(np.int64)

    def areas(self) -> np.ndarray:
        """(M,) int64 pixel count of every mask."""
        return self.bits.T.astype(np.int64) @ self.set_counts()

    def overlaps(self) -> np.ndarray:
        """(M, M) int64 pixel intersection counts (diagonal = areas): sums over the sets."""
        b = self.bits.astype(np.int64)
        return b.T @ (b * self.set_counts()[:, None])

    def mask(self, i: int) -> np.ndarray:
        """(H, W) bool mask of candidate index ``i`` (not of id ``i``; ``index_of``)."""
        return self.bits[:, int(i)][self.codes]

    def stack(self, index: np.ndarray | list[int] | None = None) -> np.ndarray:
        """(k, H, W) bool masks of the candidate indices ``index`` (all when None), newly
        materialised and not kept (k x H x W bytes)."""
        cols = self.bits if index is None else self.bits[:, np.asarray(index, np.int64).reshape(-1)]
        return np.ascontiguousarray(cols.T)[:, self.codes]

    @property
    def masks(self) -> np.ndarray:
        """(M, H, W) bool stack, read-only. Costly: materialised on first use and kept with the
        object (M x H x W bytes); see the class docstring."""
        st = self.__dict__.get("_stack")
        if st is None:
            st = _frozen_array(self.stack())
            self.__dict__["_stack"] = st  # a cache, not state: frozen fields stay as they are
        return st

    def select(self, index: np.ndarray | list[int]) -> "MaskCandidates":
        """The candidates at ``index`` (in that order), sharing this object's code image."""
        idx = np.asarray(index, np.int64).reshape(-1)
        return MaskCandidates(ids=self.ids[idx], scores=None if self.scores is None else self.scores[idx],
                              codes=self.codes, bits=self.bits[:, idx])

    def __getstate__(self) -> dict:
        return {k: v for k, v in self.__dict__.items() if k != "_stack"}  # the cache is not pickled

    def index_of(self, mask_id: int) -> int:
        hits = np.flatnonzero(self.ids == mask_id)
        if len(hits) == 0:
            raise KeyError(f"no mask with id {mask_id}")
        return int(hits[0])

    @staticmethod
    def empty(height: int, width: int) -> "MaskCandidates":
        return MaskCandidates(np.zeros((0, height, width), bool), np.zeros((0,), np.int32))


@dataclass(frozen=True, eq=False)
class View:
    """One posed RGB-D image.

    Attributes:
        frame: frame index as in the file names (``image_{frame:06d}.png``).
        rgb: (H, W, 3) uint8 colour image.
        depth: (H, W) float32 z-depth in metres, NaN for holes (0 in files is read as a hole);
            None when the frame has no depth (e.g. RGB-only post-interaction frames). Copied
            (holes made NaN) unless given as a read-only float32 array without zero or negative
            values (the loaders': 8 MB and a few passes less per 1080p view).
        camera: the camera; its size must equal the image size.
        masks: mask candidates of this view, or None when none were given.
        name: a human-readable name (the image file name when loaded).
    """

    frame: int
    rgb: np.ndarray
    camera: Camera
    depth: np.ndarray | None = None
    masks: MaskCandidates | None = None
    name: str = ""

    def __post_init__(self) -> None:
        rgb = np.asarray(self.rgb)
        H, W = self.camera.height, self.camera.width
        label = self.name or f"frame {self.frame}"
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise SceneError(f"{label}: rgb must be (H, W, 3) uint8, got {rgb.dtype} {rgb.shape}")
        if rgb.shape[:2] != (H, W):
            raise SceneError(f"{label}: image is {rgb.shape[1]}x{rgb.shape[0]} but the camera says {W}x{H}")
        object.__setattr__(self, "rgb", _frozen_array(rgb))
        object.__setattr__(self, "frame", int(self.frame))
        if self.depth is not None:
            d = np.asarray(self.depth, dtype=np.float32)
            if d.shape != (H, W):
                raise SceneError(f"{label}: depth is {d.shape[1]}x{d.shape[0]} but the camera says {W}x{H}")
            if d.flags.writeable or (d <= 0).any():  # else: a loader's frozen array, holes NaN already
                d = d.copy()  # the caller's array is left as it is
                d[~(d > 0)] = np.nan  # 0, negative and NaN are holes; inf stays and is rejected below
            if np.isinf(d).any():
                raise SceneError(f"{label}: depth contains inf")
            object.__setattr__(self, "depth", _frozen_array(d))
        if self.masks is not None and self.masks.shape != (H, W) and len(self.masks) > 0:
            raise SceneError(
                f"{label}: masks are {self.masks.shape[1]}x{self.masks.shape[0]} but the image is {W}x{H}"
            )


@dataclass(frozen=True)
class ObjectInfo:
    """One ground-truth object.

    Attributes:
        id: instance id, 0-based; pixels and points carry this id (-1 = background).
        category: a category name used for language queries ("mug", "banana").
        name: source model name (e.g. the YCB model id), free text.
        T_world_object: (4, 4) rigid object-to-world pose in metres, or None if unknown.
        color: (3,) uint8 nominal colour, or None.
    """

    id: int
    category: str
    name: str = ""
    T_world_object: np.ndarray | None = None
    color: tuple[int, int, int] | None = None

    def __post_init__(self) -> None:
        if self.T_world_object is not None:
            object.__setattr__(
                self, "T_world_object", _frozen_array(check_rigid(self.T_world_object, f"object {self.id} pose"))
            )


@dataclass(frozen=True, eq=False)
class GroundTruth:
    """Optional ground truth of a scene.

    Attributes:
        objects: the objects, ids 0..K-1 in order.
        instance_maps: frame -> (H, W) int32 per-pixel object id, -1 = background.
        points: (N, 3) float32 labelled world points in metres (from clean depth).
        point_labels: (N,) int32 object id per point, -1 = background (table, tray).
    """

    objects: tuple[ObjectInfo, ...]
    instance_maps: dict[int, np.ndarray] = field(default_factory=dict)
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    point_labels: np.ndarray = field(default_factory=lambda: np.zeros((0,), np.int32))

    def __post_init__(self) -> None:
        objs = tuple(self.objects)
        if [o.id for o in objs] != list(range(len(objs))):
            raise SceneError(f"ground-truth object ids must be 0..K-1 in order, got {[o.id for o in objs]}")
        object.__setattr__(self, "objects", objs)
        maps = {}
        for f, m in self.instance_maps.items():
            m = np.asarray(m, dtype=np.int32)
            if m.ndim != 2:
                raise SceneError(f"ground-truth instance map of frame {f} must be (H, W), got {m.shape}")
            if m.size and (m.min() < -1 or m.max() >= len(objs)):
                raise SceneError(f"ground-truth instance map of frame {f} has ids outside -1..{len(objs) - 1}")
            maps[int(f)] = _frozen_array(m)
        object.__setattr__(self, "instance_maps", maps)
        p = np.asarray(self.points, dtype=np.float32).reshape(-1, 3)
        lab = np.asarray(self.point_labels, dtype=np.int32).reshape(-1)
        if p.shape[0] != lab.shape[0]:
            raise SceneError(f"{p.shape[0]} ground-truth points but {lab.shape[0]} labels")
        object.__setattr__(self, "points", _frozen_array(p))
        object.__setattr__(self, "point_labels", _frozen_array(lab))

    @property
    def categories(self) -> tuple[str, ...]:
        return tuple(sorted({o.category for o in self.objects}))


@dataclass(frozen=True, eq=False)
class Scene:
    """A multi-view scene.

    Attributes:
        views: all views, ordered by frame.
        initial: indices into ``views`` of the initial (pre-interaction) views used for segmentation.
        post: indices into ``views`` of post-interaction views, in time order.
        ground_truth: optional ground truth (synthetic scenes, BOP scenes).
        name: scene name.
        root: the folder it was loaded from, if any.
        warnings: what the loader had to guess or work around (``diagnostics.RunWarning``),
            e.g. a frame taken as post-interaction because its depth file is missing.
    """

    views: tuple[View, ...]
    initial: tuple[int, ...]
    post: tuple[int, ...] = ()
    ground_truth: GroundTruth | None = None
    name: str = ""
    root: Path | None = None
    warnings: tuple = ()

    def __post_init__(self) -> None:
        views = tuple(self.views)
        object.__setattr__(self, "views", views)
        object.__setattr__(self, "initial", tuple(int(i) for i in self.initial))
        object.__setattr__(self, "post", tuple(int(i) for i in self.post))
        object.__setattr__(self, "warnings", tuple(self.warnings))
        frames = [v.frame for v in views]
        if len(set(frames)) != len(frames):
            raise SceneError(f"{self.name or 'scene'}: duplicate frame indices {frames}")
        n = len(views)
        for which in ("initial", "post"):
            for i in getattr(self, which):
                if not 0 <= i < n:
                    raise SceneError(f"{self.name or 'scene'}: {which} view index {i} out of range 0..{n - 1}")
        if set(self.initial) & set(self.post):
            raise SceneError(f"{self.name or 'scene'}: a view cannot be both initial and post-interaction")

    @property
    def initial_views(self) -> tuple[View, ...]:
        return tuple(self.views[i] for i in self.initial)

    @property
    def post_views(self) -> tuple[View, ...]:
        return tuple(self.views[i] for i in self.post)

    def view_by_frame(self, frame: int) -> View:
        for v in self.views:
            if v.frame == frame:
                return v
        raise KeyError(f"no view with frame {frame}")
