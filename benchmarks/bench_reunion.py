"""A/B of the reunion of split groups (``grouping.reunion_tau`` with ``reunion_max_contain``), one process.

Per scene and variant, one JSON line: AP25 / AP50 / AP, predictions, reunion merges, the CPU of
``segment`` (``time.process_time``) and of its grouping stage; then the means. Variants: ``def``
(the default), ``r25c`` (tau 0.25, containment gate 0.5), ``r12c`` (tau 0.12, gate 0.5),
``r25`` (tau 0.25, no gate); ``r12cs`` / ``r25cs`` add ``reunion_min_semantic`` 0.7. docs/benchmark/strict-iou.md, "Session 10: splits":

    .venv/bin/python benchmarks/bench_reunion.py --seeds 2 3 --difficulties easy intermediate hard \
        --cache /tmp/bench_cache --variants def r25c r12c

Seeds >= 6 other than the ones named are the lead's held-out: name fresh seeds explicitly.
"""
import argparse
import json
import time

import numpy as np
from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment

V = {"def": {}, "r25": {"grouping.reunion_tau": 0.25},
     "r25c": {"grouping.reunion_tau": 0.25, "grouping.reunion_max_contain": 0.5},
     "r12c": {"grouping.reunion_tau": 0.12, "grouping.reunion_max_contain": 0.5},
     "r12cs": {"grouping.reunion_tau": 0.12, "grouping.reunion_max_contain": 0.5, "grouping.reunion_min_semantic": 0.7},
     "r25cs": {"grouping.reunion_tau": 0.25, "grouping.reunion_max_contain": 0.5, "grouping.reunion_min_semantic": 0.7}}
ap = argparse.ArgumentParser()
ap.add_argument("--seeds", type=int, nargs="+"); ap.add_argument("--difficulties", nargs="+")
ap.add_argument("--cache"); ap.add_argument("--variants", nargs="+", default=list(V))
ap.add_argument("--depth-noise", default="realsense")
a = ap.parse_args()
lo, hi = min(a.seeds), max(a.seeds)
specs = [s for s in synth_suite(hi - lo + 1, a.difficulties, seed0=lo, depth_noise=a.depth_noise) if int(s.name[-4:]) in a.seeds]
rows = {k: [] for k in a.variants}
for spec in specs:
    scene = _load_prepared(a.cache, spec).scene
    for k in a.variants:
        t = time.process_time()
        seg = segment(scene, with_fields(SegmentConfig(), V[k]), progress=False)
        t = time.process_time() - t
        res, _ = evaluate_instances(seg.points, seg.instance, seg.scores, scene.ground_truth)
        n = sum(m.stage == "reunion" for m in seg.trace.grouping.merges)
        r = dict(scene=spec.name, v=k, ap25=round(res.ap25, 2), ap50=round(res.ap50, 2), ap=round(res.ap, 2),
                 pred=res.num_pred, reunions=n, cpu=round(t, 1),
                 reunion_cpu=round(sum(x.seconds for x in seg.trace.timings if x.stage == "grouping"), 3))
        print(json.dumps(r), flush=True)
        rows[k].append(r)
for k, rs in rows.items():
    print("MEAN", k, json.dumps({c: round(float(np.mean([r[c] for r in rs])), 2) for c in ("ap25", "ap50", "ap", "pred")}))
