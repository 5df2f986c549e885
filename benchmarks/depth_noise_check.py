"""Ours and both baselines on generated scenes with RealSense-like depth noise (a spot check).

The standard suite (docs/benchmark.md) renders clean depth; this script measures how much
sensor-like depth noise costs each method. Usage:
    .venv/bin/python benchmarks/depth_noise_check.py --seeds 3
"""

from __future__ import annotations

import argparse

import numpy as np

from clutt3r_core.baselines.maskclustering import maskclustering_baseline
from clutt3r_core.baselines.naive import naive_baseline
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.pipeline import segment
from clutt3r_core.synth import SynthConfig, generate_scene


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--depth-noise", nargs="+", default=["none", "realsense"])
    args = ap.parse_args()
    methods = {
        "ours": lambda sc: segment(sc),
        "naive": naive_baseline,
        "maskclustering (re-impl.)": maskclustering_baseline,
    }
    print("| depth noise | preset | " + " | ".join(methods) + " |")
    print("|---|---|" + "---|" * len(methods))
    for dn in args.depth_noise:
        for preset in ("easy", "intermediate", "hard"):
            rows = {m: [] for m in methods}
            for seed in range(args.seeds):
                sc = generate_scene(SynthConfig(seed=seed, preset=preset, depth_noise=dn), progress=False)
                for m, fn in methods.items():
                    p = fn(sc)
                    r, _ = evaluate_instances(p.points, p.instance, p.scores, sc.ground_truth)
                    rows[m].append((r.ap25, r.ap50, r.ap))
            cells = [" / ".join(f"{x:.1f}" for x in np.mean(rows[m], axis=0)) for m in methods]
            print(f"| {dn} | {preset} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
