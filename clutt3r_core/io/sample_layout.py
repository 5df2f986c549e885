"""The original method's sample layout (the authors' release, ``samples/*/data``).

Layout of a scene folder::

    transforms.json            nerfstudio-style: fl_x, fl_y, cx, cy, w, h,
                               frames[i] = {file_path, depth_file_path, transform_matrix}
                               transform_matrix = T_world_camera, OpenCV axes, metres
    images/                    RGB PNGs
    depth/                     uint16 PNG, millimetres, 0 = hole
    instance_masks/            mask_{frame:06d}_{id:02d}.png, 0/255 binary candidates
    instance_tree.json         (optional) a grouping in the original release's schema

Our additions, all optional, so that the same loader reads synthetic scenes:

    clutt3r_scene.json         {"name", "initial_frames": [...], "post_frames": [...]}
    gt/objects.json            [{"id", "category", "name", "T_world_object", "color"}]
    gt/instance_{frame:06d}.png  uint16, 0 = background, k + 1 = object k
    gt/points.npz              points (N, 3) float32 metres, labels (N,) int32

Which frames are initial and which are post-interaction: ``clutt3r_scene.json`` if
present; else ``instance_tree.json`` (``initial.initial_idx`` and the ``updates``
keys); else frames whose depth file exists are initial and the others post.
"""

from __future__ import annotations

import json
import re
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from clutt3r_core.diagnostics import RunWarning
from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import (
    NPZ_READ_ERRORS,
    atomic_write_bytes,
    atomic_write_npz,
    io_threads,
    read_depth_mm,
    read_label_png,
    read_masks,
    read_rgb,
    release_freed_memory,
    write_png,
)
from clutt3r_core.scene import Camera, GroundTruth, MaskCandidates, ObjectInfo, Scene, View

__all__ = ["load_sample_layout", "write_sample_layout", "is_sample_layout", "MASK_NAME"]

MASK_NAME = re.compile(r"^mask_(\d+)_(\d+)\.png$")
_DIGITS = re.compile(r"(\d+)(?!.*\d)")


def is_sample_layout(root: str | Path) -> bool:
    return (Path(root) / "transforms.json").is_file()


def _read_json(path: Path) -> object:
    if not path.is_file():
        raise SceneFileError(path, "file not found")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as e:
        raise SceneFileError(path, f"not valid JSON ({e.msg} at line {e.lineno})") from None
    except UnicodeDecodeError:
        raise SceneFileError(path, "not valid JSON (not UTF-8 text)") from None
    except OSError as e:
        raise SceneFileError(path, f"cannot be read ({e.strerror or e})") from None


def _frame_index(file_path: str, position: int) -> int:
    m = _DIGITS.search(Path(file_path).stem)
    return int(m.group(1)) if m else position


def _intrinsics(meta: dict, frame: dict, path: Path) -> tuple[np.ndarray, int, int]:
    def get(key: str) -> float:
        src = frame if key in frame else meta if key in meta else None
        if src is None:
            raise SceneFileError(path, f"missing intrinsics key '{key}'")
        try:
            return float(src[key])
        except (TypeError, ValueError):
            raise SceneFileError(path, f"intrinsics key '{key}' must be a number, got {src[key]!r}") from None

    K = np.array([[get("fl_x"), 0.0, get("cx")], [0.0, get("fl_y"), get("cy")], [0.0, 0.0, 1.0]])
    return K, int(get("w")), int(get("h"))


def _scan_masks(mask_dir: Path) -> dict[int, list[tuple[int, Path]]]:
    by_frame: dict[int, list[tuple[int, Path]]] = {}
    for p in sorted(mask_dir.iterdir()):
        m = MASK_NAME.match(p.name)
        if m:
            by_frame.setdefault(int(m.group(1)), []).append((int(m.group(2)), p))
    return by_frame


def _read_candidates(items: list[tuple[int, Path]], hw: tuple[int, int]) -> MaskCandidates:
    """One view's mask candidates from its ``_scan_masks`` entries (id, path), each mask encoded
    as it is decoded: no (M, H, W) stack is ever held (issue 13: the 1080p stacks were 240 MiB
    of the command's peak)."""
    ids = np.array([i for i, _ in items], np.int32)
    return MaskCandidates.from_masks(read_masks([p for _, p in items], hw), ids, hw)


def _frame_roles(
    root: Path, frames: list[int], has_depth: dict[int, bool]
) -> tuple[list[int], list[int], Path | None]:
    """(initial frames, post frames, the file that named them or None when inferred from depth)."""
    side = root / "clutt3r_scene.json"
    if side.is_file():
        meta = _read_json(side)
        try:
            return [int(f) for f in meta["initial_frames"]], [int(f) for f in meta.get("post_frames", [])], side
        except (KeyError, TypeError, ValueError, AttributeError):
            raise SceneFileError(side, "needs 'initial_frames' (list of frame indices)") from None
    tree = root / "instance_tree.json"
    if tree.is_file():
        meta = _read_json(tree)
        try:
            initial = [int(f) for f in meta["initial"]["initial_idx"]]
            post = sorted(int(f) for f in (meta.get("updates") or {}))
            return initial, post, tree
        except (KeyError, TypeError, ValueError, AttributeError):
            raise SceneFileError(tree, "has no 'initial.initial_idx' list") from None
    initial = [f for f in frames if has_depth[f]]
    post = [f for f in frames if not has_depth[f]]
    return initial, post, None


def load_sample_layout(root: str | Path, *, load_masks: bool = True, load_gt: bool = True) -> Scene:
    """Load a scene folder in the sample layout (see module docstring).

    Raises SceneFileError naming the file for every inconsistency: missing
    transforms.json, an image whose size differs from w/h, a depth PNG that is not
    16-bit, a mask whose size differs from its image, a non-rigid transform, an empty
    mask folder, a corrupt PNG.
    """
    root = Path(root)
    if not root.is_dir():
        raise SceneFileError(root, "scene folder not found")
    tpath = root / "transforms.json"
    if not tpath.is_file():
        raise SceneFileError(tpath, "missing: a sample-layout scene needs transforms.json")
    meta = _read_json(tpath)
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise SceneFileError(tpath, "has no 'frames' list")

    entries = []
    for i, fr in enumerate(meta["frames"]):
        if not isinstance(fr, dict) or "file_path" not in fr or "transform_matrix" not in fr:
            raise SceneFileError(tpath, f"frame {i} needs 'file_path' and 'transform_matrix'")
        for key in ("file_path", "depth_file_path"):
            if fr.get(key) is not None and not isinstance(fr[key], str):
                raise SceneFileError(tpath, f"frame {i}: '{key}' must be a string, got {fr[key]!r}")
        if not fr["file_path"]:  # found by benchmarks/fuzz_loaders.py: null reached Path() as a TypeError
            raise SceneFileError(tpath, f"frame {i}: 'file_path' must name the frame's image, got {fr['file_path']!r}")
        K, w, h = _intrinsics(meta, fr, tpath)
        try:
            T = np.asarray(fr["transform_matrix"], dtype=np.float64)
        except (TypeError, ValueError):
            # ragged or non-numeric nested lists: numpy's own message would not name the file
            raise SceneFileError(
                tpath, f"frame {i} ({fr['file_path']}): 'transform_matrix' must be a 4x4 list of numbers"
            ) from None
        try:
            cam = Camera(K, w, h, T)
        except SceneError as e:
            raise SceneFileError(tpath, f"frame {i} ({fr['file_path']}): {e}") from None
        frame = _frame_index(fr["file_path"], i)
        dpath = root / fr["depth_file_path"] if fr.get("depth_file_path") else None
        entries.append((frame, root / fr["file_path"], dpath, cam))

    frames = [e[0] for e in entries]
    if len(set(frames)) != len(frames):
        raise SceneFileError(tpath, f"duplicate frame indices {frames}")
    has_depth = {f: d is not None and d.is_file() for f, _, d, _ in entries}
    initial_frames, post_frames, roles_src = _frame_roles(root, frames, has_depth)
    unknown = (set(initial_frames) | set(post_frames)) - set(frames)
    if unknown:
        raise SceneFileError(
            roles_src or tpath,
            f"frames {sorted(unknown)} are named as initial/post but transforms.json does not list them"
            f" (it lists {sorted(frames)})",
        )
    both = set(initial_frames) & set(post_frames)
    if both:
        raise SceneFileError(roles_src or tpath, f"frames {sorted(both)} are listed as both initial and post-interaction")
    for f, _, d, _ in entries:
        if f in initial_frames and not has_depth[f]:
            raise SceneFileError(d or tpath, f"initial frame {f} has no depth file")
    warnings = _demotion_warnings(root, entries, post_frames) if roles_src is None else ()

    masks_by_frame: dict[int, list[tuple[int, Path]]] = {}
    mask_dir = root / "instance_masks"
    if load_masks and mask_dir.is_dir():
        masks_by_frame = _scan_masks(mask_dir)
        if not masks_by_frame:
            raise SceneFileError(mask_dir, "mask folder is empty (no mask_FFFFFF_MM.png files)")

    def load_view(entry: tuple) -> View:
        frame, ipath, dpath, cam = entry
        hw = (cam.height, cam.width)
        rgb = read_rgb(ipath, hw)
        depth = read_depth_mm(dpath, hw) if has_depth[frame] else None
        if depth is not None:
            depth.setflags(write=False)  # View takes a frozen depth map as is (no copy)
        masks = None
        if load_masks and mask_dir.is_dir():
            masks = _read_candidates(masks_by_frame.get(frame, []), hw)
        return View(frame=frame, rgb=rgb, camera=cam, depth=depth, masks=masks, name=ipath.name)

    with ThreadPoolExecutor(io_threads()) as pool:
        views = list(pool.map(load_view, entries))
    release_freed_memory()  # the decoding threads' arenas
    order = np.argsort([v.frame for v in views], kind="stable")
    views = [views[i] for i in order]
    index = {v.frame: i for i, v in enumerate(views)}

    gt = _load_gt(root, views) if load_gt and (root / "gt" / "objects.json").is_file() else None
    name = root.parent.name if root.name == "data" else root.name
    side = root / "clutt3r_scene.json"
    if side.is_file():
        name = str(_read_json(side).get("name", name))
    return Scene(
        views=tuple(views),
        initial=tuple(index[f] for f in initial_frames),
        post=tuple(index[f] for f in post_frames),
        ground_truth=gt,
        name=name,
        root=root,
        warnings=warnings,
    )


def _demotion_warnings(root: Path, entries: list[tuple], post_frames: list[int]) -> tuple[RunWarning, ...]:
    """One warning per frame that role inference made post-interaction (issue 14: it was silent).

    Without clutt3r_scene.json or instance_tree.json a frame without depth is taken as
    post-interaction; a depth file deleted or misnamed by accident would otherwise just
    shrink the segmentation by one view without a word.
    """
    out = []
    post = set(post_frames)
    for frame, ipath, dpath, _ in entries:
        if frame not in post:
            continue
        if dpath is None:
            why = "transforms.json gives it no depth_file_path"
        else:
            rel = dpath.relative_to(root) if dpath.is_relative_to(root) else dpath
            why = f"its depth file {rel} is missing"
        out.append(RunWarning(
            "frame-demoted",
            f"frame {frame} ({ipath.name}): {why}, so it was taken as a post-interaction frame and is not "
            "segmented (list the frames in clutt3r_scene.json to make the roles explicit)",
            frame, ipath.name))
    return tuple(out)


def _load_gt(root: Path, views: list[View]) -> GroundTruth:
    gdir = root / "gt"
    opath = gdir / "objects.json"
    raw = _read_json(opath)
    if not isinstance(raw, list):
        raise SceneFileError(opath, "must be a list of objects")
    objects = []
    for o in raw:
        if not isinstance(o, dict):  # found by benchmarks/fuzz_loaders.py: a null entry raised AttributeError
            raise SceneFileError(opath, f"each object must be a JSON object, got {o!r}")
        try:
            T = o.get("T_world_object")
            objects.append(
                ObjectInfo(
                    id=int(o["id"]),
                    category=str(o["category"]),
                    name=str(o.get("name", "")),
                    T_world_object=None if T is None else np.asarray(T, np.float64),
                    color=None if o.get("color") is None else tuple(int(c) for c in o["color"]),
                )
            )
        except (KeyError, TypeError, ValueError, SceneError) as e:
            raise SceneFileError(opath, f"bad object entry {o!r}: {e}") from None
    maps = {}
    for v in views:
        p = gdir / f"instance_{v.frame:06d}.png"
        if p.is_file():
            maps[v.frame] = read_label_png(p, (v.camera.height, v.camera.width)) - 1
    points = np.zeros((0, 3), np.float32)
    labels = np.zeros((0,), np.int32)
    ppath = gdir / "points.npz"
    if ppath.is_file():
        try:
            with np.load(ppath) as z:
                points, labels = z["points"], z["labels"]
        except (KeyError, *NPZ_READ_ERRORS) as e:
            raise SceneFileError(ppath, f"unreadable ground-truth points: {e}") from None
        # found by tests/core/robustness/test_fuzz_loaders.py: a scalar 'points' reached GroundTruth's reshape
        if points.ndim != 2 or points.shape[1] != 3 or points.dtype.kind not in "fiu":
            raise SceneFileError(ppath, f"'points' must be (N, 3) real numbers (metres), got {points.dtype} {points.shape}")
        if labels.shape != (len(points),) or labels.dtype.kind not in "iu":
            raise SceneFileError(
                ppath, f"'labels' must be ({len(points)},) integers (one per point), got {labels.dtype} {labels.shape}")
    try:
        return GroundTruth(tuple(objects), maps, points, labels)
    except SceneError as e:
        raise SceneFileError(gdir, str(e)) from None


def _write_mask(path: Path, cands: MaskCandidates, j: int) -> None:
    write_png(path, cands.mask(j))


def _dump_json(path: Path, obj: object) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=1) + "\n").encode())


def write_sample_layout(scene: Scene, root: str | Path, *, instance_tree: dict | None = None) -> Path:
    """Write ``scene`` in the sample layout. Reading it back gives the same arrays.

    Depth is written in whole millimetres: a scene whose depth is already on the
    millimetre grid (every loaded scene, every generated one) round-trips exactly.
    """
    root = Path(root)
    (root / "images").mkdir(parents=True, exist_ok=True)
    (root / "depth").mkdir(exist_ok=True)
    frames_meta = []
    cam0 = scene.views[0].camera
    with ThreadPoolExecutor(io_threads()) as pool:
        jobs = []
        for v in scene.views:
            img_rel = f"images/image_{v.frame:06d}.png"
            dep_rel = f"depth/depth_{v.frame:06d}.png"
            entry = {"file_path": img_rel, "depth_file_path": dep_rel,
                     "transform_matrix": v.camera.T_world_camera.tolist()}
            c = v.camera
            if not (np.allclose(c.K, cam0.K) and (c.width, c.height) == (cam0.width, cam0.height)):
                entry.update(fl_x=c.fx, fl_y=c.fy, cx=c.cx, cy=c.cy, w=c.width, h=c.height)
            frames_meta.append(entry)
            jobs.append(pool.submit(write_png, root / img_rel, v.rgb))
            if v.depth is not None:
                mm = np.nan_to_num(v.depth, nan=0.0) * 1000.0
                if mm.max(initial=0) > 65535:
                    raise SceneError(f"{v.name}: depth beyond 65.535 m cannot be written as uint16 mm")
                jobs.append(pool.submit(write_png, root / dep_rel, np.round(mm).astype(np.uint16)))
            if v.masks is not None and len(v.masks):
                (root / "instance_masks").mkdir(exist_ok=True)
                for j, mid in enumerate(v.masks.ids):  # each mask materialised in its job, none kept
                    jobs.append(pool.submit(_write_mask, root / "instance_masks" / f"mask_{v.frame:06d}_{mid:02d}.png",
                                            v.masks, j))
        gt = scene.ground_truth
        if gt is not None:
            (root / "gt").mkdir(exist_ok=True)
            for f, m in gt.instance_maps.items():
                jobs.append(pool.submit(write_png, root / "gt" / f"instance_{f:06d}.png", (m + 1).astype(np.uint16)))
        for j in jobs:
            j.result()
    meta = {"camera_model": "OPENCV", "fl_x": cam0.fx, "fl_y": cam0.fy, "cx": cam0.cx, "cy": cam0.cy,
            "w": cam0.width, "h": cam0.height, "frames": frames_meta}
    _dump_json(root / "transforms.json", meta)
    _dump_json(root / "clutt3r_scene.json", {
        "name": scene.name,
        "initial_frames": [scene.views[i].frame for i in scene.initial],
        "post_frames": [scene.views[i].frame for i in scene.post],
    })
    if gt is not None:
        _dump_json(root / "gt" / "objects.json", [
            {"id": o.id, "category": o.category, "name": o.name,
             "T_world_object": None if o.T_world_object is None else o.T_world_object.tolist(),
             "color": None if o.color is None else list(o.color)}
            for o in gt.objects
        ])
        atomic_write_npz(root / "gt" / "points.npz", points=gt.points, labels=gt.point_labels)
    if instance_tree is not None:
        _dump_json(root / "instance_tree.json", instance_tree)
    return root
