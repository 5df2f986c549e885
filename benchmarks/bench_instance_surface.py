"""Strict-IoU AP and distance to the GT surface with and without the per-instance surface step
(``SegmentConfig.instance_surface``, ``segmentation/instance_surface.py``; issue 13 part 2).

For each generated scene (RealSense-like depth by default) ``segment`` runs once with the default;
the step is the pipeline's last (after the vote, the rim attach and the table contact: it moves
points only), so each variant is that result with ``smooth_instances`` applied, exactly as the
pipeline applies it (``--check-pipeline`` runs ``segment`` with the first variant too and asserts
the same points). Prints per scene and variant AP25 / AP50 / AP, the off-GT and hole cells, the
labelling ceiling, and the distance of the labelled points to the clean GT surface (median and 90th
percentile, metres -> mm: each point's distance to the plane of its 12 nearest GT points of one
label), then the means:

    .venv/bin/python benchmarks/bench_instance_surface.py --seeds 2 3           # tuning
    .venv/bin/python benchmarks/bench_instance_surface.py --seeds 0 1           # check
    .venv/bin/python benchmarks/bench_instance_surface.py --seeds 0 --depth-noise none

Scenes are cached under --cache (default /tmp/bench_cache, the suite's).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.breakdown import error_breakdown
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment
from clutt3r_core.segmentation.instance_surface import InstanceSurfaceConfig, smooth_instances


def surface_distance(gt_points: np.ndarray, gt_labels: np.ndarray, q: np.ndarray, k: int = 12) -> np.ndarray:
    """Unsigned distance (metres) of q (M, 3) to the clean surface: the least-squares plane of its k
    nearest GT points that share the nearest one's label (object vs table never mixed)."""
    from scipy.spatial import cKDTree

    if not len(q):
        return np.zeros(0)
    _, idx = cKDTree(gt_points).query(q, k=k)
    P = gt_points[idx].astype(np.float64)
    w = (gt_labels[idx] == gt_labels[idx[:, :1]]).astype(np.float64)
    c = (P * w[..., None]).sum(1) / w.sum(1)[:, None]
    X = (P - c[:, None]) * w[..., None]
    _, vec = np.linalg.eigh(np.einsum("nki,nkj->nij", X, X))
    return np.abs(np.einsum("ni,ni->n", q - c, vec[:, :, 0]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--radii", type=float, nargs="+", default=[0.0, 0.010], help="instance_surface.radius, metres")
    ap.add_argument("--variants", nargs="*", default=[],
                    help="more variants as JSON objects of InstanceSurfaceConfig fields, "
                         'e.g. \'{"radius": 0.01, "leave_margin": 0.001}\'')
    ap.add_argument("--check-pipeline", action="store_true")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise=args.depth_noise)
             if int(s.name[-4:]) in args.seeds]
    variants = [{"radius": r} for r in args.radii] + [json.loads(v) for v in args.variants]
    rows: dict[str, list[dict]] = {json.dumps(v): [] for v in variants}
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene  # generated into the cache when missing
        gt = scene.ground_truth
        cfg = SegmentConfig()
        t0 = time.process_time()
        seg = segment(scene, cfg, progress=False)
        t_seg = time.process_time() - t0
        obj = seg.instance >= 0
        for var in variants:
            r = var["radius"]
            t0 = time.process_time()
            pts = (smooth_instances(seg.points, seg.instance, InstanceSurfaceConfig(**var), seg.counts,
                                    cfg.pointcloud.voxel_size).points if r > 0 else seg.points)
            t_step = time.process_time() - t0
            if args.check_pipeline and r > 0:
                other = segment(scene, with_fields(cfg, {f"instance_surface.{k}": v for k, v in var.items()}),
                                progress=False)
                assert np.array_equal(other.points, pts) and np.array_equal(other.instance, seg.instance)
            res, _ = evaluate_instances(pts, seg.instance, seg.scores, gt)
            b = error_breakdown(pts, seg.instance, seg.scores, gt)
            d = surface_distance(gt.points, gt.point_labels, pts[obj].astype(np.float64))
            row = dict(scene=spec.name, variant=var, ap25=round(res.ap25, 1), ap50=round(res.ap50, 1),
                       ap=round(res.ap, 1), pred=res.num_pred, gt=res.num_gt, ceiling=round(b.ap_all_fixed, 1),
                       off_gt_cells=b.wrong_cells[1], hole_cells=b.wrong_cells[0],
                       d_med_mm=round(1e3 * float(np.median(d)), 3),
                       d_p90_mm=round(1e3 * float(np.percentile(d, 90)), 3),
                       cpu_step_s=round(t_step, 3), cpu_segment_s=round(t_seg, 2))
            print(json.dumps(row), flush=True)
            rows[json.dumps(var)].append(row)
    for v, rs in rows.items():
        print("MEAN", v, json.dumps({c: round(float(np.mean([x[c] for x in rs])), 3)
                                            for c in ("ap25", "ap50", "ap", "pred", "ceiling", "off_gt_cells",
                                                      "hole_cells", "d_med_mm", "d_p90_mm", "cpu_step_s",
                                                      "cpu_segment_s")}))


if __name__ == "__main__":
    main()
