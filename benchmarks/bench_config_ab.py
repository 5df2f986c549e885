"""Strict-IoU AP of the default against config variants, one process, the same cached scenes.

For each generated scene (RealSense-like depth by default; seeds 2-3 are the tuning scenes,
0-1 the check) ``segment`` runs with ``SegmentConfig()`` and with each variant, one after the
other; prints AP25 / AP50 / AP and instances per scene and variant (``--breakdown``: the
labelling kinds' oracle gains too), then the means and the summed CPU seconds:

    .venv/bin/python benchmarks/bench_config_ab.py --seeds 2 3 \\
        --variant smooth:vote.smooth_max_size=3,vote.smooth_min_agree=5

A variant is ``NAME:FIELD=VALUE,FIELD=VALUE`` with dotted ``SegmentConfig`` fields and JSON
values. Scenes are cached under --cache (default /tmp/bench_cache, the suite's); seeds >= 6
are the lead's held-out scenes and are refused.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.breakdown import ERROR_KINDS, SENSOR_KINDS, error_breakdown
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment


def parse_variant(text: str) -> tuple[str, dict]:
    name, _, rest = text.partition(":")
    fields = {}
    for kv in filter(None, rest.split(",")):
        key, _, val = kv.partition("=")
        fields[key] = json.loads(val)
    return name, fields


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--variant", nargs="*", default=[], help="NAME:FIELD=VALUE,... (JSON values)")
    ap.add_argument("--breakdown", action="store_true")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    if max(args.seeds) >= 6:
        raise SystemExit("seeds >= 6 are held out")
    variants = [("default", {})] + [parse_variant(v) for v in args.variant]
    specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise=args.depth_noise)
             if int(s.name[-4:]) in args.seeds]
    rows: dict[str, list[dict]] = {n: [] for n, _ in variants}
    for spec in specs:
        scene = _load_prepared(args.cache, spec).scene
        gt = scene.ground_truth
        line = [spec.name]
        for name, fields in variants:
            t = time.process_time()
            seg = segment(scene, with_fields(SegmentConfig(), fields), progress=False)
            cpu = time.process_time() - t
            res, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            r = dict(ap25=res.ap25, ap50=res.ap50, ap=res.ap, pred=res.num_pred, cpu=cpu)
            text = f"{name}: {res.ap25:.1f}/{res.ap50:.1f}/{res.ap:.1f} ({res.num_pred}/{res.num_gt})"
            if args.breakdown:
                b = error_breakdown(seg.points, seg.instance, seg.scores, gt)
                text += " " + json.dumps({k: round(x, 1) for k, x in zip(ERROR_KINDS, b.ap_gain) if k not in SENSOR_KINDS})
            rows[name].append(r)
            line.append(text)
        print(" | ".join(line), flush=True)
    for name, rs in rows.items():
        means = " / ".join(f"{np.mean([r[c] for r in rs]):.2f}" for c in ("ap25", "ap50", "ap", "pred"))
        print("MEAN", name, "AP25 / AP50 / AP / instances", means, f"CPU {sum(r['cpu'] for r in rs):.1f} s")


if __name__ == "__main__":
    main()
