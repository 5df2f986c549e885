"""Fusion variants on the bench's own generated scenes: fusion cell statistics and the pipeline's AP.

How the third pass of docs/benchmark/strict-iou.md was measured (issue 13, part 2). Per scene and
per value of ``PointCloudConfig.surface_rim_neighbours``: the fused cloud's *hole* (GT object cells
of 10 mm with no fused point) and *off* (fused cells within two cells of an object where the GT has
none), both per GT object cell, counted with the rim voxels (``FusedCloud.rim``); then ``segment``
with that config, ``evaluate_instances`` and the ``error_breakdown``, exactly as
``evaluation.jobs.run_job``. The rim voxels are attached after the vote (the default) or, with
``--join``, segmented with the cloud (``surface_rim_attach_k`` 0, the first measurement).

    .venv/bin/python benchmarks/bench_fusion_fill.py --seeds 2 3 --rim 0 1
    .venv/bin/python benchmarks/bench_fusion_fill.py --seeds 2 3 --rim 0 1 --join
    .venv/bin/python benchmarks/bench_fusion_fill.py --seeds 0 1 --rim 0 1 --depth-noise none

Scenes come from ``evaluation.runner.synth_suite`` (the standard suite's specs) and are cached
under --cache (the bench's scene cache layout: a ``clutt3r bench --cache`` folder is reused).
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
from scipy.spatial import cKDTree

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.breakdown import error_breakdown
from clutt3r_core.evaluation.metrics import evaluate_instances, voxelize_labels
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment
from clutt3r_core.pointcloud import fuse_views


def cell_stats(points: np.ndarray, gt) -> tuple[float, float]:
    """(hole, off) in percent of the GT object cells (module docstring)."""
    gv = voxelize_labels(gt.points, gt.point_labels)
    gobj = {tuple(c) for c, lab in zip(gv.cells, gv.labels) if lab >= 0}
    gall = {tuple(c) for c in gv.cells}
    fc = {tuple(c) for c in np.floor(points / gv.voxel).astype(np.int64)}
    off = np.array(sorted(fc - gall))
    near = int((cKDTree(np.array(sorted(gobj))).query(off)[0] <= 2.0).sum()) if len(off) else 0
    return 100.0 * len(gobj - fc) / len(gobj), 100.0 * near / len(gobj)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--rim", type=int, nargs="+", default=[0, 1], help="surface_rim_neighbours values")
    ap.add_argument("--join", action="store_true", help="rim voxels segmented with the cloud (attach_k 0)")
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise=args.depth_noise)
             if int(s.name[-4:]) in args.seeds]
    rows = {k: [] for k in args.rim}
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene  # generated into the cache when missing
        gt = scene.ground_truth
        for k in args.rim:
            cfg = with_fields(SegmentConfig(), {"pointcloud.surface_rim_neighbours": k,
                                                **({"pointcloud.surface_rim_attach_k": 0} if args.join else {})})
            t = time.process_time()
            cloud = fuse_views(scene.initial_views, cfg.pointcloud)
            t_fuse = time.process_time() - t
            pts = cloud.points if cloud.rim is None else np.concatenate([cloud.points, cloud.rim.points])
            hole, off = cell_stats(pts, gt)
            seg = segment(scene, cfg, progress=False)
            res, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            b = error_breakdown(seg.points, seg.instance, seg.scores, gt)
            r = dict(scene=spec.name, rim=k, voxels=len(pts), fuse_cpu_s=round(t_fuse, 2), hole=round(hole, 1),
                     off=round(off, 1), ap25=round(res.ap25, 1), ap50=round(res.ap50, 1), ap=round(res.ap, 1),
                     pred=res.num_pred, gt=res.num_gt, ceiling=round(b.ap_all_fixed, 1),
                     boundary_gain=round(b.gain("boundary"), 1))
            print(json.dumps(r), flush=True)
            rows[k].append(r)
    for k, rs in rows.items():
        keys = [c for c in rs[0] if c not in ("scene", "rim")]
        print("MEAN rim", k, json.dumps({c: round(float(np.mean([r[c] for r in rs])), 2) for c in keys}))


if __name__ == "__main__":
    main()
