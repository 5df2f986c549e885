"""Strict-IoU AP with and without the spanning-mask rule (``vote.span_cover``, sessions 9 and 10).

For each generated scene (RealSense-like depth by default), ``segment`` runs once per config
variant, one after the other in one process (``bench_table_contact.py``'s pattern); prints AP25 /
AP50 / AP, instances, the number of cleared (mask, super-voxel) occupancies and of masks with one, and the
CPU seconds of the rule and of the whole ``segment`` per scene as JSON lines, and for every variant
after the first the GT objects whose best IoU crosses 0.5 against the first (``lost50`` /
``gained50``: indices into the scene's objects), then the means:

    .venv/bin/python benchmarks/bench_span.py --seeds 2 3                     # tuning
    .venv/bin/python benchmarks/bench_span.py --seeds 0 1                     # check
    .venv/bin/python benchmarks/bench_span.py --seeds 10 11 12 13 --seed0 10 \\
        --difficulties intermediate hard --cache /tmp/h5/cache                # fresh seeds

``--variant NAME:FIELD=VALUE,...`` (repeatable, JSON values; default ``off:vote.span_cover=0``,
``s9:vote.span_cover=0.5,vote.span_instances_only=false,vote.span_min_views=0`` (session 9's rule
without its guards) and ``on:vote.span_cover=0.5`` (the default since session 10)). Seeds 6-9 and
18-21 are the lead's held-out: never name them.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment

from bench_config_ab import parse_variant  # this folder's sibling script


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--seed0", type=int, default=0, help="first seed of the suite the scenes were generated in")
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--variant", action="append", default=[], help="NAME:FIELD=VALUE,...")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    if any(6 <= s <= 9 or 18 <= s <= 21 for s in args.seeds):
        raise SystemExit("seeds 6-9 and 18-21 are the lead's held-out")
    specs = [s for s in synth_suite(max(args.seeds) - args.seed0 + 1, args.difficulties,
                                    depth_noise=args.depth_noise, seed0=args.seed0)
             if int(s.name[-4:]) in args.seeds]
    variants = dict(parse_variant(v) for v in (args.variant or [
        "off:vote.span_cover=0", "s9:vote.span_cover=0.5,vote.span_instances_only=false,vote.span_min_views=0",
        "on:vote.span_cover=0.5"]))
    rows: dict[str, list[dict]] = {k: [] for k in variants}
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene
        gt = scene.ground_truth
        first = None  # best IoU per GT object under the first variant
        for name, fields in variants.items():
            t0 = time.process_time()
            seg = segment(scene, with_fields(SegmentConfig(), fields), progress=False)
            cpu = time.process_time() - t0
            res, m = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            best = m.iou.max(axis=0) if m.iou.size else np.zeros(m.num_gt)
            sc = seg.trace.vote.span_cleared
            r = dict(scene=spec.name, variant=name, ap25=round(res.ap25, 1), ap50=round(res.ap50, 1),
                     ap=round(res.ap, 1), pred=res.num_pred, gt=res.num_gt,
                     cleared=0 if sc is None else int(len(sc)),
                     masks_cleared=0 if sc is None else int(len(np.unique(sc[:, 0]))),
                     segment_cpu_s=round(cpu, 2), vote_s=round(seg.trace.timing("vote"), 3))
            if first is None:
                first = best
            else:
                r["lost50"] = np.flatnonzero((first >= 0.5) & (best < 0.5)).tolist()
                r["gained50"] = np.flatnonzero((first < 0.5) & (best >= 0.5)).tolist()
            print(json.dumps(r), flush=True)
            rows[name].append(r)
    for name, rs in rows.items():
        print("MEAN", name, json.dumps({c: round(float(np.mean([r[c] for r in rs])), 2)
                                        for c in ("ap25", "ap50", "ap", "pred")}))


if __name__ == "__main__":
    main()
