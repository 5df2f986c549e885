"""Loader for one scene folder in the BOP format (e.g. a GraspClutter6D scene).

Layout read here (BOP "scenewise" format, one folder per scene)::

    scene_camera.json    {im_id: {cam_K: 9 floats row-major (pixels),
                                  cam_R_w2c: 9 floats row-major, cam_t_w2c: 3 floats (MILLIMETRES),
                                  depth_scale: depth PNG value * depth_scale = millimetres}}
    rgb/{im:06d}.png     colour image (.jpg also accepted)
    depth/{im:06d}.png   uint16 depth, 0 = hole
    scene_gt.json        (optional) {im_id: [{obj_id, cam_R_m2c, cam_t_m2c (mm)}, ...]}
    mask_visib/{im:06d}_{k:06d}.png  (optional) visible mask of GT instance k in image im
    instance_masks/      (optional, our addition) mask candidates named as in the sample
                         layout, mask_{im:06d}_{id:02d}.png; BOP itself ships none

Conversions to docs/conventions.md:

* BOP poses are world-to-camera in millimetres; ``T_world_camera`` is the inverse of
  ``[R_w2c | t_w2c / 1000]``, in metres. GraspClutter6D's real captures have no world
  frame of their own: the one defined by ``cam_R_w2c`` / ``cam_t_w2c`` is used as is
  (it need not be z up).
* Depth in metres = PNG value * depth_scale / 1000.
* Ground-truth instance ``k`` (the k-th entry of an image's ``scene_gt.json`` list) is
  object id ``k``. The list must name the same objects in the same order in every
  loaded image, which holds for BOP's static multi-view scenes.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import io_threads, read_depth_mm, read_mask, read_rgb, release_freed_memory
from clutt3r_core.io.sample_layout import _read_candidates, _read_json, _scan_masks
from clutt3r_core.scene import Camera, GroundTruth, ObjectInfo, Scene, View, check_rigid

__all__ = ["load_bop_scene", "is_bop_scene", "paint_instances", "voxel_labelled_points", "GT_POINT_VOXEL_M"]

# ours: labelled GT points are back-projected from every pixel of every initial view
# (millions at 1920x1080); one point per 2 mm voxel keeps the cloud small while staying
# far finer than any object in the benchmarks (smallest YCB/GC6D parts are ~1 cm).
GT_POINT_VOXEL_M = 0.002
# ours: the farthest camera or object from the world origin a tabletop scene can have (1 km:
# three orders of magnitude above any real capture, far below where voxel keys overflow)
_MAX_TRANSLATION_M = 1000.0
_RGB_EXTS = (".png", ".jpg", ".jpeg")


def is_bop_scene(root: str | Path) -> bool:
    return (Path(root) / "scene_camera.json").is_file()


def _numbers(path: Path, entry: object, key: str, n: int, where: str, what: str) -> np.ndarray:
    """``entry[key]`` as (n,) float64, or SceneFileError naming ``path`` and ``where``."""
    if not isinstance(entry, Mapping) or key not in entry:
        raise SceneFileError(path, f"{where} has no '{key}' ({what})")
    try:
        a = np.asarray(entry[key], dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        raise SceneFileError(path, f"{where}: '{key}' must be {n} numbers ({what}), got {entry[key]!r}")
    return a


def _rigid_from_bop(path: Path, R: np.ndarray, t_mm: np.ndarray, where: str) -> np.ndarray:
    """4x4 metres transform from a BOP rotation (9,) and translation (3,) in millimetres."""
    dist = float(np.abs(t_mm).max()) / 1000.0  # max, not the norm: squaring 1e300 overflows
    if dist > _MAX_TRANSLATION_M:
        # found by fuzzing: 1e300 mm passed as finite and overflowed in the GT voxel grid (numpy
        # RuntimeWarnings on the terminal, garbage labels); no tabletop camera is that far away
        raise SceneFileError(path, f"{where}: translation of {dist:.3g} m is implausible (BOP translations are "
                                   f"millimetres; more than {_MAX_TRANSLATION_M:g} m is refused)")
    T = np.eye(4)
    T[:3, :3] = R.reshape(3, 3)
    T[:3, 3] = t_mm / 1000.0
    try:
        return check_rigid(T, where)
    except SceneError as e:
        raise SceneFileError(path, str(e)) from None


def _invert(T: np.ndarray) -> np.ndarray:
    R, t = T[:3, :3], T[:3, 3]
    out = np.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ t
    return out


def _image_ids(path: Path, raw: object, what: str) -> dict[int, object]:
    if not isinstance(raw, Mapping):
        raise SceneFileError(path, f"must be a JSON object keyed by image id ({what})")
    out = {}
    for key, value in raw.items():
        try:
            out[int(key)] = value
        except ValueError:
            raise SceneFileError(path, f"key {key!r} is not an image id (an integer)") from None
    return out


def _rgb_path(root: Path, im: int) -> Path:
    for ext in _RGB_EXTS:
        p = root / "rgb" / f"{im:06d}{ext}"
        if p.is_file():
            return p
    raise SceneFileError(root / "rgb" / f"{im:06d}.png", "file not found (nor .jpg / .jpeg)")


def paint_instances(masks: np.ndarray) -> np.ndarray:
    """Per-pixel instance map from (K, H, W) bool visible masks: (H, W) int32, -1 = none.

    BOP's visible masks should not overlap; where annotation noise makes them do, the
    smaller mask wins (a small object in front of a large one is the usual cause), and
    between equal areas the later instance wins. Masks are painted largest first, so
    the loop runs over instances, not pixels.
    """
    masks = np.asarray(masks, dtype=bool)
    K = masks.shape[0]
    out = np.full(masks.shape[1:], -1, np.int32)
    areas = masks.sum(axis=(1, 2))
    for k in np.lexsort((np.arange(K), -areas)):  # area descending, then index ascending
        out[masks[k]] = k
    return out


def voxel_labelled_points(points: np.ndarray, labels: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """Subsample labelled points to one per ``voxel`` (metres) cube.

    Returns (centroids (V, 3) float32 metres, labels (V,) int32): the centroid of all
    points in a voxel and the most frequent label among them (ties -> smaller label).
    """
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    labels = np.asarray(labels, dtype=np.int64).reshape(-1)
    if len(points) == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0,), np.int32)
    if labels.min() < -1:
        raise SceneError(f"point labels must be >= -1, got {int(labels.min())}")
    q = np.floor(points / voxel).astype(np.int64)
    q -= q.min(axis=0)
    dims = q.max(axis=0) + 1
    key = (q[:, 0] * dims[1] + q[:, 1]) * dims[2] + q[:, 2]
    # one sort of (voxel, label) pair keys serves both the centroids and the majority vote;
    # sorted pair keys are grouped by voxel, labels ascending inside a group
    L = int(labels.max()) + 2
    pairs, inv, count = np.unique(key * L + (labels + 1), return_inverse=True, return_counts=True)
    sums = np.stack([np.bincount(inv, weights=points[:, i], minlength=len(pairs)) for i in range(3)], axis=1)
    pair_vox, pair_label = pairs // L, pairs % L - 1
    starts = np.flatnonzero(np.r_[True, pair_vox[1:] != pair_vox[:-1]])
    centroid = np.add.reduceat(sums, starts, axis=0) / np.add.reduceat(count, starts)[:, None]
    # per voxel the pair with the highest count; stable sort keeps the smaller label on ties
    group = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(pairs)]))
    order = np.lexsort((-count, group))
    first = order[np.r_[0, np.flatnonzero(np.diff(group[order])) + 1]]
    return centroid.astype(np.float32), pair_label[first].astype(np.int32)


def load_bop_scene(
    scene_dir: str | Path,
    *,
    frames: Iterable[int] | None = None,
    initial: Iterable[int] | None = None,
    post: Iterable[int] | None = None,
    mask_dir: str = "mask_visib",
    categories: Mapping[int, str] | None = None,
    gt_voxel_m: float = GT_POINT_VOXEL_M,
    load_gt: bool = True,
) -> Scene:
    """Load one BOP scene folder (see the module docstring) as a Scene.

    Args:
        scene_dir: the scene folder, e.g. ``.../test/000001``.
        frames: image ids to load; default: ``initial`` + ``post`` if either is given,
            else every image in ``scene_camera.json``.
        initial: image ids used for segmentation; default: every loaded image not in ``post``.
        post: post-interaction image ids, in time order; default none (BOP scenes are static).
        mask_dir: folder of per-instance visible masks used for the ground truth.
        categories: BOP ``obj_id`` -> category name; objects not in it get ``obj_{obj_id:06d}``.
        gt_voxel_m: voxel size (metres) of the labelled ground-truth points.
        load_gt: False: ``scene_gt.json`` and ``mask_dir`` are not read (no ground truth; what
            a segmentation needs).

    Ground truth (only when ``scene_gt.json`` exists): one ObjectInfo per instance of
    the first loaded image, ``T_world_object`` from that image's ``cam_R_m2c`` /
    ``cam_t_m2c`` and camera pose; instance maps from ``mask_dir`` (see
    ``paint_instances`` for overlaps; none when the folder is absent); labelled points
    back-projected from the depth of the initial views with those maps, background
    (-1) included, one per ``gt_voxel_m`` voxel.

    View.masks is None unless an ``instance_masks/`` folder (sample-layout names) exists.
    Raises SceneFileError naming the file for every missing or inconsistent input.
    """
    root = Path(scene_dir)
    if not root.is_dir():
        raise SceneFileError(root, "scene folder not found")
    cpath = root / "scene_camera.json"
    if not cpath.is_file():
        raise SceneFileError(cpath, "missing: a BOP scene folder needs scene_camera.json")
    cams = _image_ids(cpath, _read_json(cpath), "per-image camera parameters")
    if not cams:
        raise SceneFileError(cpath, "lists no images")

    # materialise once: the arguments may be one-shot iterators
    post_ids = [int(f) for f in post] if post is not None else []
    initial_given = [int(f) for f in initial] if initial is not None else None
    if frames is not None:
        frame_ids = sorted({int(f) for f in frames})
    elif initial_given is not None or post is not None:
        frame_ids = sorted(set(initial_given or []) | set(post_ids))
    else:
        frame_ids = sorted(cams)
    if not frame_ids:
        raise SceneError(f"{root}: no images selected")
    initial_ids = initial_given if initial_given is not None else [f for f in frame_ids if f not in post_ids]
    missing = sorted(set(frame_ids) - set(cams))
    if missing:
        raise SceneFileError(cpath, f"images {missing} were requested but have no entry here")
    outside = sorted((set(initial_ids) | set(post_ids)) - set(frame_ids))
    if outside:
        raise SceneError(f"{root}: initial/post images {outside} are not among the loaded frames {frame_ids}")

    # parse every camera entry before reading any image, so file errors come in a fixed order
    parsed = {}
    for im in frame_ids:
        entry, where = cams[im], f"image {im}"
        K = _numbers(cpath, entry, "cam_K", 9, where, "intrinsics, row-major").reshape(3, 3)
        R = _numbers(cpath, entry, "cam_R_w2c", 9, where, "world-to-camera rotation, row-major")
        t = _numbers(cpath, entry, "cam_t_w2c", 3, where, "world-to-camera translation, mm")
        T_camera_world = _rigid_from_bop(cpath, R, t, f"{where}: cam_R_w2c/cam_t_w2c")
        scale = entry.get("depth_scale", 1.0)  # BOP: absent means the PNG is already in mm
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not scale > 0:
            raise SceneFileError(cpath, f"{where}: 'depth_scale' must be a positive number, got {scale!r}")
        parsed[im] = (K, _invert(T_camera_world), float(scale))

    gt_objs, gt_lists = _parse_gt(root, frame_ids, categories, parsed) if load_gt else (None, None)
    vis_dir = root / mask_dir
    use_vis = gt_lists is not None and vis_dir.is_dir()

    cand_dir = root / "instance_masks"
    cands: dict[int, list[tuple[int, Path]]] | None = None
    if cand_dir.is_dir():
        cands = _scan_masks(cand_dir)
        if not cands:
            raise SceneFileError(cand_dir, "mask folder is empty (no mask_FFFFFF_MM.png files)")

    def load_view(im: int) -> tuple[View, np.ndarray | None]:
        K, T_world_camera, scale = parsed[im]
        ipath = _rgb_path(root, im)
        rgb = read_rgb(ipath)
        h, w = rgb.shape[:2]
        try:
            cam = Camera(K, w, h, T_world_camera)
        except SceneError as e:
            raise SceneFileError(cpath, f"image {im}: {e}") from None
        dpath = root / "depth" / f"{im:06d}.png"
        depth = None
        if dpath.is_file():
            depth = read_depth_mm(dpath, (h, w), scale=scale * 0.001)
            depth.setflags(write=False)  # View takes a frozen depth map as is (no copy)
        elif im in initial_ids:
            raise SceneFileError(dpath, f"initial image {im} has no depth file")
        masks = None
        if cands is not None:
            masks = _read_candidates(cands.get(im, []), (h, w))
        imap = None
        if use_vis:
            n = len(gt_lists[im])
            vis = [read_mask(vis_dir / f"{im:06d}_{k:06d}.png", (h, w)) for k in range(n)]
            imap = paint_instances(np.stack(vis) if vis else np.zeros((0, h, w), bool))
        return View(frame=im, rgb=rgb, camera=cam, depth=depth, masks=masks, name=ipath.name), imap

    with ThreadPoolExecutor(io_threads()) as pool:
        loaded = list(pool.map(load_view, frame_ids))  # frame_ids is sorted: views come in frame order
    release_freed_memory()  # the decoding threads' arenas
    views = [v for v, _ in loaded]
    index = {v.frame: i for i, v in enumerate(views)}

    gt = None
    if gt_objs is not None:
        maps = {v.frame: m for v, m in loaded if m is not None}
        pts, labs = [], []
        for f in initial_ids:
            v = views[index[f]]
            if f in maps and v.depth is not None:
                p, pix = v.camera.backproject(v.depth)
                pts.append(p)
                labs.append(maps[f].reshape(-1)[pix])
        if pts:
            points, labels = voxel_labelled_points(np.concatenate(pts), np.concatenate(labs), gt_voxel_m)
        else:
            points, labels = np.zeros((0, 3), np.float32), np.zeros((0,), np.int32)
        gt = GroundTruth(tuple(gt_objs), maps, points, labels)

    return Scene(
        views=tuple(views),
        initial=tuple(index[f] for f in initial_ids),
        post=tuple(index[f] for f in post_ids),
        ground_truth=gt,
        name=root.name,
        root=root,
    )


def _parse_gt(
    root: Path,
    frame_ids: list[int],
    categories: Mapping[int, str] | None,
    parsed: dict[int, tuple[np.ndarray, np.ndarray, float]],
) -> tuple[list[ObjectInfo] | None, dict[int, list] | None]:
    """Objects (ids 0..K-1) and the per-image instance lists of scene_gt.json, or (None, None)."""
    gpath = root / "scene_gt.json"
    if not gpath.is_file():
        return None, None
    raw = _image_ids(gpath, _read_json(gpath), "per-image object poses")
    lists: dict[int, list] = {}
    obj_ids: dict[int, list[int]] = {}
    for im in frame_ids:
        if im not in raw:
            raise SceneFileError(gpath, f"has no entry for image {im}")
        insts = raw[im]
        if not isinstance(insts, list):
            raise SceneFileError(gpath, f"image {im}: must be a list of instances, got {type(insts).__name__}")
        ids = []
        for k, inst in enumerate(insts):
            try:
                ids.append(int(inst["obj_id"]))
            except (KeyError, TypeError, ValueError):
                raise SceneFileError(gpath, f"image {im}, instance {k}: needs an integer 'obj_id'") from None
        lists[im], obj_ids[im] = insts, ids
    ref = frame_ids[0]
    for im in frame_ids[1:]:
        if obj_ids[im] != obj_ids[ref]:
            raise SceneFileError(
                gpath,
                f"image {im} lists objects {obj_ids[im]} but image {ref} lists {obj_ids[ref]}; instance k"
                " must be the same object in every image of a static scene",
            )
    T_world_camera = parsed[ref][1]
    objects = []
    for k, (inst, obj_id) in enumerate(zip(lists[ref], obj_ids[ref])):
        where = f"image {ref}, instance {k}"
        R = _numbers(gpath, inst, "cam_R_m2c", 9, where, "model-to-camera rotation, row-major")
        t = _numbers(gpath, inst, "cam_t_m2c", 3, where, "model-to-camera translation, mm")
        T_camera_object = _rigid_from_bop(gpath, R, t, f"{where}: cam_R_m2c/cam_t_m2c")
        name = f"obj_{obj_id:06d}"
        category = name
        if categories is not None:  # keys may be ints or, from a JSON file, strings
            category = str(categories.get(obj_id, categories.get(str(obj_id), name)))
        objects.append(ObjectInfo(id=k, category=category, name=name, T_world_object=T_world_camera @ T_camera_object))
    return objects, lists
