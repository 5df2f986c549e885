"""Strict-IoU AP with the weak-echo rule (``refine.weak_echo_ratio``) on top of the default, one process.

For each generated scene (RealSense-like depth by default) ``segment`` runs with ``SegmentConfig()``
and with each ratio, one after the other; prints per scene and ratio AP25 / AP50 / AP, instances,
how many points the rule leaves unlabelled that the default labels (``unlabelled``; and the share of
them in 10 mm cells where the clean GT surface has no point, ``off_gt_share``: the rule's claim is
that they are noise off the surface), the labelling ceiling, then the means; and the CPU of
``weak_echoes`` itself against the whole ``segment`` of the default (same process):

    .venv/bin/python benchmarks/bench_weak_echo.py --seeds 2 3 --ratios 0.1 0.2 0.3   # tuning
    .venv/bin/python benchmarks/bench_weak_echo.py --seeds 0 1 --ratios 0.2           # check
    .venv/bin/python benchmarks/bench_weak_echo.py --seeds 0 --depth-noise none        # clean depth
    .venv/bin/python benchmarks/bench_weak_echo.py --seeds 2 --ratios 0.2 --base 'pointcloud.surface="voxel-mean"'

``--geometry`` also reports whether the labels the geometry consumers read
(``update.geometry.run_geometry``: the grasp request's target, the update state) are the
default's, point for point. Scenes are cached under --cache (default /tmp/bench_cache, the
suite's); seeds >= 6 are the lead's held-out scenes and are refused.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.breakdown import ERROR_KINDS, error_breakdown
from clutt3r_core.evaluation.metrics import EVAL_VOXEL, evaluate_instances
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment
from clutt3r_core.segmentation.refine import weak_echoes
from clutt3r_core.update.geometry import run_geometry
from clutt3r_core.update.run_labels import fused_count

from bench_config_ab import parse_variant  # this folder's sibling script


def off_gt(points: np.ndarray, gt_points: np.ndarray) -> np.ndarray:
    """(N,) bool: points whose 10 mm evaluation cell holds no GT point (object or table)."""
    cells = {tuple(c) for c in np.unique(np.floor(gt_points / EVAL_VOXEL).astype(np.int64), axis=0)}
    q = np.floor(points / EVAL_VOXEL).astype(np.int64)
    return np.array([tuple(c) not in cells for c in q], bool)


def cells_cleared(points: np.ndarray, before: np.ndarray, after: np.ndarray, gt_points: np.ndarray) -> tuple[int, int]:
    """10 mm cells that hold an object-labelled point before and none after: (in cells with a GT
    point, i.e. true surface lost; in cells with none, i.e. off-GT noise removed)."""
    def labelled(lab):
        return {tuple(c) for c in np.unique(np.floor(points[lab >= 0] / EVAL_VOXEL).astype(np.int64), axis=0)}

    gone = np.array(sorted(labelled(before) - labelled(after)), np.int64).reshape(-1, 3)
    if not len(gone):
        return 0, 0
    miss = off_gt((gone + 0.5) * EVAL_VOXEL, gt_points)
    return int((~miss).sum()), int(miss.sum())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--ratios", type=float, nargs="+", default=[0.1, 0.2, 0.3])
    ap.add_argument("--geometry", action="store_true")
    ap.add_argument("--base", default="", help="FIELD=VALUE,... (JSON values) set in every variant, the default too")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    if max(args.seeds) >= 6:
        raise SystemExit("seeds >= 6 are held out")
    specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise=args.depth_noise)
             if int(s.name[-4:]) in args.seeds]
    base_fields = parse_variant("base:" + args.base)[1]
    variants = [("default", 0.0)] + [(f"echo{r:g}", r) for r in args.ratios]
    rows: dict[str, list[dict]] = {n: [] for n, _ in variants}
    cpu_seg, cpu_echo = 0.0, 0.0
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene
        gt = scene.ground_truth
        base = None
        for name, ratio in variants:
            t = time.process_time()
            seg = segment(scene, with_fields(SegmentConfig(), {**base_fields, "refine.weak_echo_ratio": ratio}), progress=False)
            dt = time.process_time() - t
            res, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            b = error_breakdown(seg.points, seg.instance, seg.scores, gt)
            r = dict(scene=spec.name, variant=name, ap25=round(res.ap25, 1), ap50=round(res.ap50, 1),
                     ap=round(res.ap, 1), pred=res.num_pred, gt=res.num_gt, ceiling=round(b.ap_all_fixed, 1),
                     labelled=int((seg.instance >= 0).sum()), points=len(seg.instance), cpu_s=round(dt, 2),
                     hole_cells=int(b.wrong_cells[ERROR_KINDS.index("hole")]),
                     off_gt_cells=int(b.wrong_cells[ERROR_KINDS.index("off_gt")]))
            if base is None:
                base = seg
                n = fused_count(seg)
                t = time.process_time()
                weak_echoes(seg.points[:n], seg.normals[:n], seg.counts[:n], seg.trace.config.pointcloud.voxel_size, 0.2)
                cpu_echo += time.process_time() - t
                cpu_seg += dt
            else:
                assert np.array_equal(seg.points, base.points), "the rule must not move points"
                lost = (base.instance >= 0) & (seg.instance < 0)
                r["unlabelled"] = int(lost.sum())
                r["unlabelled_share"] = round(float(lost.sum() / max(1, (base.instance >= 0).sum())), 4)
                r["off_gt_share"] = round(float(off_gt(seg.points[lost], gt.points).mean()), 3) if lost.any() else None
                r["cells_cleared_gt"], r["cells_cleared_off_gt"] = cells_cleared(seg.points, base.instance,
                                                                                 seg.instance, gt.points)
                r["other_changes"] = int(((base.instance != seg.instance) & ~lost).sum())
                if args.geometry:
                    r["geometry_equal"] = bool(np.array_equal(run_geometry(seg), run_geometry(base)))
            print(json.dumps(r), flush=True)
            rows[name].append(r)
    for name, rs in rows.items():
        print("MEAN", name, json.dumps({c: round(float(np.mean([r[c] for r in rs])), 2)
                                        for c in ("ap25", "ap50", "ap", "pred", "ceiling")}))
    print("CPU weak_echoes / segment (default, same process):", round(cpu_echo, 3), "/", round(cpu_seg, 2), "s",
          f"({100 * cpu_echo / max(cpu_seg, 1e-9):.2f} %)")


if __name__ == "__main__":
    main()
