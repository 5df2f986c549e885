"""AP with and without the duplicate-masks rule on generated scenes whose candidates carry copies.

Usage:
    .venv/bin/python benchmarks/bench_duplicates.py [--seeds 0 1] [--p-copy 0.3] [--width 640 --height 480]

The generator's Grounded-SAM-like candidates never contain two copies of one mask (the rule then
changes nothing), while real Grounded SAM returns some masks twice (docs/benchmark/real-agreement.md).
This script generates one scene per difficulty and seed (8 views, RealSense-like depth, like
``clutt3r bench``), then gives every non-table candidate of every view, with probability
``--p-copy``, a copy: the same mask with a one-pixel boundary ring removed on a random side half
(pixel IoU about 0.9-0.98 at 640x480, lower for small masks, which the rule then leaves alone).
It runs ``segment`` with ``grouping.duplicate_iou`` 0.9 (ours) and 0 (off) on the same scene and
prints AP25 / AP50 / AP (``evaluation.metrics.evaluate_instances``) and the instance count of both.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def with_copies(scene, p: float, seed: int):
    """``scene`` with copies of its candidates (module docstring); returns (scene, number of copies)."""
    from scipy.ndimage import binary_erosion

    from clutt3r_core.scene import MaskCandidates, Scene

    rng = np.random.default_rng(seed)
    initial = {scene.views[i].frame for i in scene.initial}
    views, n = [], 0
    for v in scene.views:
        m = v.masks
        if m is None or not len(m) or v.frame not in initial:
            views.append(v)
            continue
        h, w = m.shape
        extra, ids = [], []
        for k in range(len(m)):
            mask = m.masks[k]
            if mask.sum() > 0.3 * h * w or rng.uniform() >= p:  # the table / tray mask keeps no copy
                continue
            ring = mask & ~binary_erosion(mask)
            yy, xx = np.nonzero(ring)
            side = rng.uniform(-1, 1, 2)
            c = np.array([yy.mean(), xx.mean()]) if len(yy) else np.zeros(2)
            drop = ((yy - c[0]) * side[0] + (xx - c[1]) * side[1]) > 0
            copy = mask.copy()
            copy[yy[drop], xx[drop]] = False
            extra.append(copy)
            ids.append(int(m.ids.max()) + 1 + len(ids))
        n += len(extra)
        if extra:
            m = MaskCandidates(np.concatenate([m.masks, np.stack(extra)]), np.concatenate([m.ids, ids]))
        views.append(replace(v, masks=m))
    return Scene(tuple(views), scene.initial, scene.post, scene.ground_truth, scene.name), n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    ap.add_argument("--p-copy", type=float, default=0.3)
    ap.add_argument("--width", type=int, default=640)
    ap.add_argument("--height", type=int, default=480)
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    a = ap.parse_args()

    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.evaluation.metrics import evaluate_instances
    from clutt3r_core.pipeline import segment
    from clutt3r_core.synth import SynthConfig, generate_scene

    configs = {"ours": SegmentConfig(), "rule off": with_fields(SegmentConfig(), {"grouping.duplicate_iou": 0.0})}
    rows = []
    print("| scene | copies | GT | ours AP25 / AP50 / AP (instances) | rule off AP25 / AP50 / AP (instances) |")
    print("|---|---|---|---|---|")
    for d in a.difficulties:
        for seed in a.seeds:
            t0 = time.perf_counter()
            base = generate_scene(SynthConfig(seed=seed, preset=d, views=8, width=a.width, height=a.height,
                                              mask_noise="grounded-sam-like", depth_noise="realsense"), progress=False)
            scene, n = with_copies(base, a.p_copy, seed)
            cells = []
            for name, cfg in configs.items():
                seg = segment(scene, cfg)
                r, _ = evaluate_instances(seg.points, seg.instance, seg.scores, scene.ground_truth)
                cells.append((r.ap25, r.ap50, r.ap, seg.num_instances))
            rows.append(cells)
            print(f"| {d} {seed} | {n} | {r.num_gt} | " + " | ".join(
                f"{c[0]:.1f} / {c[1]:.1f} / {c[2]:.1f} ({c[3]})" for c in cells) + f" |  ({time.perf_counter() - t0:.0f} s)",
                flush=True)
    mean = np.mean([[c[:3] for c in cells] for cells in rows], axis=0)
    print(f"| mean | | | {mean[0][0]:.1f} / {mean[0][1]:.1f} / {mean[0][2]:.1f} | "
          f"{mean[1][0]:.1f} / {mean[1][1]:.1f} / {mean[1][2]:.1f} |")


if __name__ == "__main__":
    main()
