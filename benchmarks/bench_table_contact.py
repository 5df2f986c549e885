"""Strict-IoU AP with and without the table-contact rule (``refine.contact_height``, issue 13 part 2).

For each generated scene (RealSense-like depth by default), ``segment`` runs with the rule off
and with 2 mm (the default since session 8: measured above each object's own support level,
``refine.contact_labels``), one after the other in one process; prints AP25 / AP50 / AP, instances,
the labelling ceiling and the ``error_breakdown`` per scene as JSON lines, then the means:

    .venv/bin/python benchmarks/bench_table_contact.py --seeds 2 3     # tuning
    .venv/bin/python benchmarks/bench_table_contact.py --seeds 0 1     # held-out

``--boundary`` also splits the breakdown's boundary cells into object cells left unlabelled,
object cells labelled with another object, and GT-background (table) cells labelled as an object.
``--variant NAME:FIELD=VALUE,FIELD=VALUE`` (repeatable; JSON values, ``bench_config_ab.parse_variant``)
runs named config variants instead of ``--heights``, e.g. the session-8 contact rule (support
levels, fill and contact):

    .venv/bin/python benchmarks/bench_table_contact.py --seeds 2 3 --variant off:refine.contact_height=0 \
        --variant fill:refine.contact_height=0.003,refine.contact_fill_low=0.004,refine.contact_fill_high=0.012

Scenes are cached under --cache (default /tmp/bench_cache, the suite's).
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.breakdown import ERROR_KINDS, _near_other_label, error_breakdown
from clutt3r_core.evaluation.metrics import EVAL_VOXEL, evaluate_instances, union_cells, voxelize_labels
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment

from bench_config_ab import parse_variant  # this folder's sibling script


def boundary_split(seg, gt) -> dict[str, int]:
    """The breakdown's boundary cells by what went wrong (own prediction: most cells, as a close
    approximation of the breakdown's dominant-GT rule)."""
    cells, lp, lg, in_pred, in_gt = union_cells(voxelize_labels(seg.points, seg.instance, EVAL_VOXEL),
                                                voxelize_labels(gt.points, gt.point_labels, EVAL_VOXEL))
    tgt = np.full(len(cells), -1)
    for g in np.unique(lg[lg >= 0]):
        m = lg == g
        v, c = np.unique(lp[m & (lp >= 0)], return_counts=True)
        if len(v):
            tgt[m] = v[np.argmax(c)]
    wrong = (lp != tgt) & (in_pred | (lg >= 0))
    b = wrong & ~((lg >= 0) & ~in_pred) & ~(~in_gt & (lp >= 0)) & _near_other_label(cells, lg, in_gt)
    return {"object_unlabelled": int((b & (lg >= 0) & (lp < 0)).sum()),
            "object_as_other_object": int((b & (lg >= 0) & (lp >= 0)).sum()),
            "table_as_object": int((b & (lg < 0) & (lp >= 0)).sum())}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--heights", type=float, nargs="+", default=[0.0, 0.002], help="contact_height values, metres")
    ap.add_argument("--variant", action="append", default=[], help="NAME:FIELD=VALUE,... (replaces --heights)")
    ap.add_argument("--boundary", action="store_true")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise=args.depth_noise)
             if int(s.name[-4:]) in args.seeds]
    variants = dict(parse_variant(v) for v in args.variant)
    if not variants:
        variants = {str(h): {"refine.contact_height": h} for h in args.heights}
    rows: dict[str, list[dict]] = {k: [] for k in variants}
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene  # generated into the cache when missing
        gt = scene.ground_truth
        for h, fields in variants.items():
            seg = segment(scene, with_fields(SegmentConfig(), fields), progress=False)
            res, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            b = error_breakdown(seg.points, seg.instance, seg.scores, gt)
            r = dict(scene=spec.name, variant=h, ap25=round(res.ap25, 1), ap50=round(res.ap50, 1),
                     ap=round(res.ap, 1), pred=res.num_pred, gt=res.num_gt, ceiling=round(b.ap_all_fixed, 1),
                     gain={k: round(g, 1) for k, g in zip(ERROR_KINDS, b.ap_gain)},
                     cells={k: c for k, c in zip(ERROR_KINDS, b.wrong_cells)}, gt_cells=b.gt_cells)
            if args.boundary:
                r["boundary_split"] = boundary_split(seg, gt)
            print(json.dumps(r), flush=True)
            rows[h].append(r)
    for h, rs in rows.items():
        print("MEAN", h, json.dumps({c: round(float(np.mean([r[c] for r in rs])), 2)
                                                     for c in ("ap25", "ap50", "ap", "pred", "ceiling")}))


if __name__ == "__main__":
    main()
