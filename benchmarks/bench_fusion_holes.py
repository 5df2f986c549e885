"""Strict-IoU AP and the hole / off-GT cells for fusion variants (session 9, the holes; issue 13 part 2).

For each generated scene (RealSense-like depth by default) ``segment`` runs with the default and
with each ``--variant NAME:FIELD=VALUE,...`` (JSON values, ``bench_config_ab.parse_variant``), one
after the other in one process, alternating per scene; prints per scene and variant AP25 / AP50 /
AP, instances, the labelling ceiling, the breakdown's hole and off-GT cells and their oracle
gains, the result's points, the rim voxels, and the CPU seconds of ``segment`` (process time: the machine is shared) and the pipeline timer's seconds of its
``pointcloud`` and ``attach`` stages, then the means:

    .venv/bin/python benchmarks/bench_fusion_holes.py --seeds 2 3 --variant moved1:pointcloud.surface_rim_moved=1

Scenes are cached under --cache (default /tmp/bench_cache, the suite's). Seeds >= 6 are refused
(held out).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.breakdown import ERROR_KINDS, error_breakdown
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment

from bench_config_ab import parse_variant  # this folder's sibling script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--variant", action="append", default=[], help="NAME:FIELD=VALUE,... (JSON values)")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    if max(args.seeds) >= 6:
        raise SystemExit("seeds 6-9 are held out")
    specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise=args.depth_noise)
             if int(s.name[-4:]) in args.seeds]
    variants = dict([("default", {})] + [parse_variant(v) for v in args.variant])
    rows: dict[str, list[dict]] = {k: [] for k in variants}
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene  # generated into the cache when missing
        gt = scene.ground_truth
        for name, fields in variants.items():
            t0 = time.process_time()
            seg = segment(scene, with_fields(SegmentConfig(), fields), progress=False)
            cpu = time.process_time() - t0
            res, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            b = error_breakdown(seg.points, seg.instance, seg.scores, gt)
            stages = {t.stage: t.seconds for t in seg.trace.timings}
            surf = seg.trace.surface
            r = dict(scene=spec.name, variant=name, ap25=round(res.ap25, 1), ap50=round(res.ap50, 1),
                     ap=round(res.ap, 1), pred=res.num_pred, gt=res.num_gt, ceiling=round(b.ap_all_fixed, 1),
                     hole=b.wrong_cells[ERROR_KINDS.index("hole")], off_gt=b.wrong_cells[ERROR_KINDS.index("off_gt")],
                     hole_gain=round(b.ap_gain[ERROR_KINDS.index("hole")], 1), gt_cells=b.gt_cells,
                     points=len(seg.points), rim=surf.rim if surf is not None else 0,
                     cpu_segment=round(cpu, 2), t_pointcloud=round(stages.get("pointcloud", float("nan")), 2),
                     t_attach=round(stages.get("attach", 0.0), 3))
            print(json.dumps(r), flush=True)
            rows[name].append(r)
    for name, rs in rows.items():
        print("MEAN", name, json.dumps({c: round(float(np.mean([r[c] for r in rs])), 2)
                                        for c in ("ap25", "ap50", "ap", "pred", "ceiling", "hole", "off_gt", "points",
                                                  "cpu_segment")}))


if __name__ == "__main__":
    main()
