"""A run folder: what ``clutt3r segment SCENE --out RUN`` writes, and how it is found and read.

    instances.npz        points (N,3) f32, colors (N,3) u8, instance (N,) i32 (-1 none), scores (K,) f32
    instances.ply        the same cloud with per-vertex colour and instance id
    instance_tree.json   the grouping in the original release's schema (schema_version 1)
    cloud.npz            normals, voxel counts, super-voxel labels and support flags
    trace/               trace.npz + trace.json (every intermediate, see segmentation/trace.py)
    run.json             scene name, the scene folder it was made from, the tool version, and
                         the run's warnings ([{code, frame, view, message}], diagnostics.RunWarning),
                         and where its mask candidates came from (masks: {generator, folder, generated})
    instance_masks/      generated candidates (masks.MaskProvenance), mask_{frame:06d}_{id:02d}.png;
                         absent when the scene's own were used
    overview.png         (CLI only) instances splatted into up to four views

The scene folder is recorded relative to the run folder when a relative path exists
(``os.path.relpath``), so a run and its scene moved together keep working; otherwise
absolute. Every file is written atomically.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clutt3r_core.diagnostics import RunWarning
from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import NPZ_READ_ERRORS, atomic_write_bytes, atomic_write_npz
from clutt3r_core.masks import MaskProvenance

__all__ = [
    "RUN_FILES",
    "RunInfo",
    "is_run_folder",
    "missing_run_file",
    "save_run",
    "load_run",
    "run_voxel_size",
    "read_run_info",
    "run_scene_folder",
    "ply_bytes",
]

RUN_FILES: tuple[str, ...] = ("instances.npz", "cloud.npz", "trace/trace.json", "trace/trace.npz")
"""The files ``load_run`` needs: their presence is what makes a folder a run folder."""

_RUN_JSON = "run.json"


def missing_run_file(folder: str | Path, names: tuple[str, ...] = RUN_FILES) -> Path | None:
    """The first of ``names`` (default: all ``RUN_FILES``) missing in ``folder``, or None."""
    folder = Path(folder)
    for name in names:
        if not (folder / name).is_file():
            return folder / name
    return None


def is_run_folder(path: str | Path) -> bool:
    """True when ``path`` is a folder holding every file a run needs (``RUN_FILES``)."""
    path = Path(path)
    return path.is_dir() and missing_run_file(path) is None


@dataclass(frozen=True)
class RunInfo:
    """What ``run.json`` records.

    Attributes:
        scene_name: name of the segmented scene ("" if unknown).
        scene: the scene folder as recorded (relative to the run folder, or absolute), None if none.
        created_by: the clutt3r version that wrote the run ("" for runs older than this field).
        warnings: what degraded the run's input (``diagnostics.RunWarning``, e.g. a frame demoted to
            post-interaction, a view without usable depth); empty for runs older than this field.
        masks: where the candidates came from (``masks.MaskProvenance`` without the arrays); the
            scene's own for runs older than this field.
    """

    scene_name: str = ""
    scene: Path | None = None
    created_by: str = ""
    warnings: tuple[RunWarning, ...] = ()
    masks: MaskProvenance = MaskProvenance()


def _version() -> str:
    try:
        from importlib.metadata import version

        return version("clutt3r")
    except Exception:  # not installed as a distribution (a source checkout on sys.path)
        return "unknown"


def save_run(seg, out: str | Path, scene_root: str | Path | None = None) -> Path:
    """Write the run folder of ``seg`` (a ``pipeline.Segmentation``) to ``out`` (module docstring).

    ``scene_root``: the scene folder the run was made from, recorded in run.json so that
    the viewer finds the images without ``--scene``.
    """
    from clutt3r_core.pipeline import instance_tree_json  # pipeline imports this module
    from clutt3r_core.segmentation.trace import save_trace

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # points and normals are stored, not deflated: float32 coordinates shrink by only 13-15 %
    # at zlib level 1 for 0.12 s of CPU per 640x480 8-view run (about 0.6 MB more; issue 13)
    atomic_write_npz(
        out / "instances.npz", points=seg.points.astype(np.float32), colors=seg.colors.astype(np.uint8),
        instance=seg.instance.astype(np.int32), scores=seg.scores.astype(np.float32), stored=("points",))
    atomic_write_npz(
        out / "cloud.npz", normals=seg.normals.astype(np.float32), counts=seg.counts.astype(np.int32),
        sv_labels=seg.sv_labels.astype(np.int32), sv_support=seg.sv_support.astype(bool), stored=("normals",))
    atomic_write_bytes(out / "instances.ply", ply_bytes(seg.points, seg.colors, seg.instance))
    atomic_write_bytes(out / "instance_tree.json", json.dumps(instance_tree_json(seg), indent=1).encode())
    save_trace(seg.trace, out / "trace")
    _write_run_masks(seg.masks, out / "instance_masks")
    info = {"scene_name": seg.scene_name, "scene": None, "created_by": _version(),
            "warnings": [w.to_json() for w in seg.warnings], "masks": seg.masks.to_json()}
    if scene_root is not None:
        scene_abs = Path(scene_root).resolve()
        try:
            info["scene"] = os.path.relpath(scene_abs, out.resolve())
        except ValueError:  # no relative path (another drive on Windows)
            info["scene"] = str(scene_abs)
    atomic_write_bytes(out / _RUN_JSON, json.dumps(info, indent=1).encode())
    return out


def _write_run_masks(prov: MaskProvenance, folder: Path) -> None:
    """Generated candidates into ``folder``; a previous run's mask PNGs there are removed first,
    since the viewer reads the folder whole (``masks.with_run_masks``) and must not mix runs."""
    from clutt3r_core.masks.formats import write_png_masks

    if folder.is_dir():
        for old in folder.glob("mask_*.png"):
            old.unlink()
        if not prov.candidates and not any(folder.iterdir()):
            folder.rmdir()
    for frame, cands in zip(prov.frames, prov.candidates):
        write_png_masks(folder, frame, cands)


def run_voxel_size(seg) -> float:
    """The fused cloud's voxel edge of a run's ``pipeline.Segmentation`` (metres;
    ``SegmentConfig.pointcloud.voxel_size``), 0.005 when its trace records none: the spacing the
    update's state and a grasp request in an updated scene declare."""
    return float(getattr(getattr(seg.trace.config, "pointcloud", None), "voxel_size", 0.005))


def load_run(folder: str | Path):
    """Read a run folder written by ``save_run`` (a ``pipeline.Segmentation``) without recomputing."""
    from clutt3r_core.pipeline import Segmentation  # pipeline imports this module
    from clutt3r_core.segmentation.trace import load_trace

    folder = Path(folder)
    missing = missing_run_file(folder)
    if missing is not None:
        raise SceneFileError(missing, "missing: not a clutt3r run folder")
    info = read_run_info(folder)
    a, c = _read_npz(folder / "instances.npz"), _read_npz(folder / "cloud.npz")
    try:
        trace = load_trace(folder / "trace")
    except SceneFileError:
        raise
    except (KeyError, TypeError, IndexError, AttributeError, ValueError, OverflowError) as e:
        # a trace edited or damaged by hand (found by fuzzing trace.json: non-UTF-8 bytes, ragged
        # lists, out-of-range ints); SceneError is a ValueError and lands here too
        raise SceneFileError(folder / "trace", f"damaged trace ({type(e).__name__}: {e})") from None
    try:
        return Segmentation(
            points=a["points"], colors=a["colors"], normals=c["normals"], counts=c["counts"],
            instance=a["instance"], scores=a["scores"], sv_labels=c["sv_labels"], sv_support=c["sv_support"],
            trace=trace, scene_name=info.scene_name, warnings=info.warnings, masks=info.masks,
        )
    except KeyError as e:
        raise SceneFileError(folder, f"run arrays lack {e}") from None
    except (SceneError, ValueError, TypeError) as e:  # arrays of the wrong shape or kind: a damaged run
        raise SceneFileError(folder, f"inconsistent run arrays: {e}") from None


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """Every array of an npz file, or SceneFileError naming it (truncated, not a zip, ...)."""
    try:
        with np.load(path) as f:
            return dict(f)
    except NPZ_READ_ERRORS as e:
        raise SceneFileError(path, f"unreadable run arrays ({e}); the run is damaged, segment the scene again") from None


def read_run_info(folder: str | Path) -> RunInfo:
    """``run.json`` of a run folder; an empty ``RunInfo`` when the run has none (older runs)."""
    path = Path(folder) / _RUN_JSON
    if not path.is_file():
        return RunInfo()
    try:
        d = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise SceneFileError(path, f"unreadable: {e}") from None
    if not isinstance(d, dict):
        raise SceneFileError(path, "expected a JSON object")
    name, scene, by = d.get("scene_name", ""), d.get("scene"), d.get("created_by", "")
    if not isinstance(name, str) or not isinstance(by, str) or not (scene is None or isinstance(scene, str)):
        raise SceneFileError(path, "scene_name, scene and created_by must be strings (scene may be null)")
    raw = d.get("warnings", [])
    if not isinstance(raw, list):
        raise SceneFileError(path, "'warnings' must be a list")
    try:
        warnings = tuple(RunWarning.from_json(w) for w in raw)
    except SceneError as e:
        raise SceneFileError(path, f"bad entry in 'warnings': {e}") from None
    try:
        masks = MaskProvenance.from_json(d["masks"]) if "masks" in d else MaskProvenance()
    except SceneError as e:
        raise SceneFileError(path, str(e)) from None
    return RunInfo(scene_name=name, scene=None if scene is None else Path(scene), created_by=by,
                   warnings=warnings, masks=masks)


def run_scene_folder(run_dir: str | Path) -> Path | None:
    """The scene folder recorded by the run (absolute), None when none was recorded.

    Raises ``SceneFileError(run.json, ...)`` when one is recorded but no longer exists.
    """
    run_dir = Path(run_dir)
    scene = read_run_info(run_dir).scene
    if scene is None:
        return None
    p = scene if scene.is_absolute() else (run_dir.resolve() / scene)
    p = Path(os.path.normpath(p))
    if not p.is_dir():
        raise SceneFileError(run_dir / _RUN_JSON, f"recorded scene folder {p} does not exist (moved?); pass --scene")
    return p


def ply_bytes(points: np.ndarray, colors: np.ndarray, instance: np.ndarray) -> bytes:
    """Binary little-endian PLY of (N, 3) points, (N, 3) uint8 colours and an int instance per vertex."""
    n = len(points)
    header = (
        "ply\nformat binary_little_endian 1.0\n"
        f"element vertex {n}\n"
        "property float x\nproperty float y\nproperty float z\n"
        "property uchar red\nproperty uchar green\nproperty uchar blue\n"
        "property int instance\nend_header\n"
    ).encode()
    rec = np.empty(n, dtype=[("p", "<f4", 3), ("c", "u1", 3), ("i", "<i4")])
    rec["p"], rec["c"], rec["i"] = points, colors, instance
    return header + rec.tobytes()
