"""A corrected run as evaluation data: ground truth in the layout the generator writes.

``export_ground_truth(run, out)`` writes a scene folder the benchmark reads
(``evaluation.runner.folder_suite`` / ``clutt3r bench --scenes``)::

    transforms.json, images/, depth/, instance_masks/, clutt3r_scene.json   the run's scene, re-written
    gt/points.npz                 points (N, 3) float32 metres = the run's points; labels (N,) int32
    gt/objects.json               [{"id", "category", "name", "T_world_object": null, "color"}]
    gt/instance_{frame:06d}.png   uint16, 0 = background, k + 1 = object k (every view)
    gt/coco/instance_{frame:06d}.json   COCO (images / annotations / categories), compressed RLE
    gt/scannet_instances.txt      one line per point of gt/points.npz: category_id * 1000 + k + 1, 0 = none
    gt/scannet_categories.json    {"1": "mug", ...} the category ids of that file
    gt/export_info.json           provenance: run folder, log entries, log SHA-256, time

The labels are the run's corrected labelling (``Annotations.current``, ids compacted:
deleted / empty instances dropped, the rest renumbered in id order), so scoring the run's
own corrected labels against this folder gives AP 100 by construction; the point of the
folder is to score *other* methods / settings on a real scene that had no ground truth.

Per-view instance maps: the labels are transferred to the pixels the camera saw. With a
depth image, each valid pixel is back-projected and takes the label of the nearest run
point within ``ExportConfig.max_gap_m`` (the depth image is the z-buffer: only the visible
surface is labelled, occluded points never paint through). Without depth, the points are
splatted with a z-buffer (nearest point wins per pixel, each point a square of its
projected voxel size).
"""

from __future__ import annotations

import dataclasses
import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clutt3r_core.corrections import CorrectedLabels
from clutt3r_core.errors import SceneError, SceneFileError

__all__ = ["ExportConfig", "ExportSummary", "project_labels", "corrected_ground_truth", "export_ground_truth"]


@dataclass(frozen=True)
class ExportConfig:
    """How labels reach the pixels.

    Attributes:
        max_gap_m: metres; a depth pixel whose back-projected point is farther than this from
            every run point stays background (ours: the benchmark's 10 mm evaluation voxel,
            ``evaluation.metrics.EVAL_VOXEL``: a pixel farther than one evaluation cell from
            the labelled cloud is not something the run reconstructed).
        splat_voxel_m: metres; footprint of one point when a view has no depth (ours: half
            the evaluation voxel, about a fused cloud's point spacing).
        default_category: category text of an instance nobody named (ours).
    """

    max_gap_m: float = 0.01
    splat_voxel_m: float = 0.005
    default_category: str = "object"

    def __post_init__(self) -> None:
        if not (self.max_gap_m > 0 and self.splat_voxel_m > 0):
            raise SceneError("ExportConfig: max_gap_m and splat_voxel_m must be > 0 metres")


@dataclass(frozen=True)
class ExportSummary:
    """What ``export_ground_truth`` wrote.

    Attributes:
        out: the scene folder.
        num_objects: instances exported (K').
        labelled_points / num_points: points with an object label / all points.
        views: frames with an instance map.
        pixels_labelled: (V,) int64 object pixels per view, in ``views`` order.
    """

    out: Path
    num_objects: int
    labelled_points: int
    num_points: int
    views: tuple[int, ...]
    pixels_labelled: np.ndarray


def project_labels(points: np.ndarray, labels: np.ndarray, camera, depth: np.ndarray | None,
                   config: ExportConfig = ExportConfig()) -> np.ndarray:
    """(H, W) int32 label per pixel of ``camera`` (-1 = background) from world ``points`` (N, 3)
    metres with ``labels`` (N,) int (-1 = none); ``depth`` (H, W) metres (NaN = hole) or None.
    Only labelled points paint; unlabelled ones still occlude (they are surface too)."""
    H, W = camera.height, camera.width
    out = np.full((H, W), -1, np.int32)
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    lab = np.asarray(labels).reshape(-1)
    if len(pts) == 0:
        return out
    if depth is not None:
        from scipy.spatial import cKDTree

        xw, flat = camera.backproject(np.asarray(depth, np.float64))
        v, u = np.divmod(flat, W)
        dist, idx = cKDTree(pts).query(xw, k=1, distance_upper_bound=config.max_gap_m, workers=1)
        ok = np.isfinite(dist)
        out[v[ok], u[ok]] = lab[idx[ok]]
        return out
    # no depth: the update stage's splat z-buffer over the points themselves
    from clutt3r_core.update.project import render_labels

    return render_labels(pts, lab, camera, config.splat_voxel_m)[0]


def corrected_ground_truth(points: np.ndarray, labels: CorrectedLabels, views=(),
                           config: ExportConfig = ExportConfig()):
    """``scene.GroundTruth`` of the corrected ``labels`` on the run's ``points``: compacted ids,
    categories (unnamed -> ``config.default_category``), an instance map per view in ``views``."""
    from clutt3r_core.scene import GroundTruth, ObjectInfo

    inst, _, cats = labels.compact()
    if len(inst) != len(points):
        raise SceneError(f"{len(points)} points but {len(inst)} labels")
    objects = tuple(ObjectInfo(id=k, category=c or config.default_category, name=c or f"instance {k}")
                    for k, c in enumerate(cats))
    maps = {v.frame: project_labels(points, inst, v.camera, v.depth, config) for v in views}
    return GroundTruth(objects, maps, np.asarray(points, np.float32), inst)


def _coco(frame: int, file_name: str, m: np.ndarray, objects) -> dict:
    from clutt3r_core.masks.formats import rle_encode, rle_string_encode

    h, w = m.shape
    cat_ids = {c: i + 1 for i, c in enumerate(sorted({o.category for o in objects}))}
    anns = []
    for o in objects:
        mask = m == o.id
        if not mask.any():
            continue
        ys, xs = np.nonzero(mask)
        anns.append({
            "id": len(anns) + 1, "image_id": frame, "category_id": cat_ids[o.category], "instance_id": o.id,
            "segmentation": {"size": [h, w], "counts": rle_string_encode(rle_encode(mask))},
            "area": int(mask.sum()), "iscrowd": 0,
            "bbox": [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)],
        })
    return {"images": [{"id": frame, "file_name": file_name, "height": h, "width": w}],
            "annotations": anns, "categories": [{"id": i, "name": c} for c, i in cat_ids.items()]}


def export_ground_truth(run_dir: str | Path, out: str | Path, scene: str | Path | None = None,
                        config: ExportConfig = ExportConfig()) -> ExportSummary:
    """Write the corrected run ``run_dir`` as a benchmark scene folder ``out`` (module docstring).

    ``scene``: the run's scene folder (default: the one recorded in run.json). Reads the
    corrections read-only (an editor may hold the log open meanwhile). Raises SceneFileError
    when ``out`` already holds ground truth (never overwritten) or the scene is missing.
    """
    from clutt3r_core.annotations import Annotations
    from clutt3r_core.io import load_scene
    from clutt3r_core.io.images import atomic_write_bytes
    from clutt3r_core.io.sample_layout import write_sample_layout
    from clutt3r_core.runs import run_scene_folder

    from clutt3r_core.runs import missing_run_file

    run_dir, out = Path(run_dir), Path(out)
    missing = missing_run_file(run_dir, ("instances.npz", "cloud.npz"))
    if missing is not None:
        raise SceneFileError(missing, "missing: not a clutt3r run folder")
    if (out / "gt" / "objects.json").exists():
        raise SceneFileError(out / "gt", "already holds ground truth; export to a new folder")
    scene_dir = Path(scene) if scene is not None else run_scene_folder(run_dir)
    if scene_dir is None:
        raise SceneFileError(run_dir / "run.json", "records no scene folder; pass --scene")
    ann = Annotations.open(run_dir, readonly=True)
    try:
        with np.load(run_dir / "instances.npz") as z:
            points = z["points"].astype(np.float32)
    except (OSError, KeyError, ValueError) as e:
        raise SceneFileError(run_dir / "instances.npz", f"unreadable: {e}") from None
    sc = load_scene(scene_dir)
    gt = corrected_ground_truth(points, ann.current, sc.views, config)
    write_sample_layout(dataclasses.replace(sc, ground_truth=gt), out)
    gdir = out / "gt"
    (gdir / "coco").mkdir(exist_ok=True)
    for v in sc.views:
        rec = _coco(v.frame, f"images/image_{v.frame:06d}.png", gt.instance_maps[v.frame], gt.objects)
        atomic_write_bytes(gdir / "coco" / f"instance_{v.frame:06d}.json", json.dumps(rec).encode())
    cat_ids = {c: i + 1 for i, c in enumerate(sorted({o.category for o in gt.objects}))}
    obj_cat = np.array([cat_ids[o.category] for o in gt.objects] + [0], np.int64)  # [-1] -> 0
    lab = gt.point_labels.astype(np.int64)
    code = np.where(lab >= 0, obj_cat[lab] * 1000 + lab + 1, 0)
    atomic_write_bytes(gdir / "scannet_instances.txt", ("\n".join(map(str, code.tolist())) + "\n").encode())
    atomic_write_bytes(gdir / "scannet_categories.json",
                       json.dumps({str(i): c for c, i in cat_ids.items()}, indent=1).encode())
    log = ann.log_path
    info = {"run": str(run_dir.resolve()), "scene": str(Path(scene_dir).resolve()), "log_entries": ann.num_ops,
            "edits_in_effect": ann.num_edits,
            "log_sha256": _sha256(log) if log.is_file() else None, "exported": time.time(),
            "config": dataclasses.asdict(config)}
    atomic_write_bytes(gdir / "export_info.json", (json.dumps(info, indent=1) + "\n").encode())
    frames = tuple(v.frame for v in sc.views)
    return ExportSummary(out, len(gt.objects), int((lab >= 0).sum()), len(lab), frames,
                         np.array([(gt.instance_maps[f] >= 0).sum() for f in frames], np.int64))


def _sha256(path: Path) -> str:
    import hashlib

    return hashlib.sha256(path.read_bytes()).hexdigest()
