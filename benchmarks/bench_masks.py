"""Benchmark the mask generators: candidate quality, end-to-end AP, real-sample agreement, time.

Usage:
    .venv/bin/python benchmarks/bench_masks.py --scenes /tmp/s/easy-0 /tmp/s/hard-0 ... \
        [--samples /work/shared/data/clutt3r-samples] [--no-e2e] [--overlays docs/masks] [--out bench_masks.json]
        [--set levels="(0.3,0.6)"]

Scenes are generated ones (``clutt3r synth --out DIR --preset P --seed S``) with ground truth;
their preset is read from gt/synth_info.json. For each scene:

- per view, the builtin generator's candidates against the GT instance maps: recall of GT
  objects (>= 100 visible pixels) by a candidate at IoU 0.5 and 0.75, candidates per view,
  share of parents / leaves in the view's containment forest (the pipeline's own tree
  builder), seconds per view; the same recall for the scene's Grounded-SAM-like candidates;
- end to end (unless ``--no-e2e``): ``segment()`` with the scene's Grounded-SAM-like
  candidates and with the builtin ones, AP@25 / AP@50 / AP (clutt3r_core.evaluation.metrics,
  10 mm grid, the benchmark's protocol).

On the real samples: how many of their Grounded-SAM *leaf* masks (leaves of the view's
containment forest) one of ours matches at IoU >= 0.5 and vice versa (our leaves against all
of theirs), per view; time per view at the samples' resolutions (seq1 640x480, seq4
1920x1080); overlay PNGs (ours | theirs) for one view each.
Not a unit test: wall times depend on the machine and its load (printed); CPU time
(``time.process_time``, all threads of the process) much less so.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from clutt3r_core.io import load_scene
from clutt3r_core.masks.builtin import BuiltinMaskConfig, builtin_candidates
from clutt3r_core.masks.quality import leaf_masks, mask_iou_matrix, view_quality
from clutt3r_core.scene import MaskCandidates


def _preset(root: Path) -> str:
    p = root / "gt" / "synth_info.json"
    if p.is_file():
        d = json.loads(p.read_text())
        return d.get("config", d).get("preset", "?") if isinstance(d, dict) else "?"
    return "?"


def overlay(rgb: np.ndarray, cands: MaskCandidates, leaves_only: bool = True) -> np.ndarray:
    """RGB with each (leaf) candidate in its own colour, outlines in white."""
    import cv2

    masks = leaf_masks(cands) if leaves_only else cands.masks
    out = rgb.astype(np.float32).copy()
    rng = np.random.default_rng(1)
    for m in sorted(masks, key=lambda m: -m.sum()):
        c = rng.integers(40, 255, 3).astype(np.float32)
        out[m] = 0.45 * out[m] + 0.55 * c
        edge = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_GRADIENT, np.ones((3, 3), np.uint8)) > 0
        out[edge] = 255
    return out.astype(np.uint8)


def scene_bench(root: Path, cfg: BuiltinMaskConfig, e2e: bool) -> dict:
    from clutt3r_core.evaluation.metrics import evaluate_instances
    from clutt3r_core.pipeline import segment

    sc = load_scene(root)
    gt = sc.ground_truth
    rows = []
    ours_views = {}
    for v in sc.initial_views:
        t, tc = time.perf_counter(), time.process_time()
        c = builtin_candidates(v, cfg)
        dt, dcpu = time.perf_counter() - t, time.process_time() - tc
        q = view_quality(c, gt.instance_maps[v.frame])
        qg = view_quality(v.masks, gt.instance_maps[v.frame])
        rows.append(dict(r50=q.recall(0.5), r75=q.recall(0.75), n=q.num_candidates, parents=q.num_parents,
                         leaves=q.num_leaves, seconds=dt, cpu_seconds=dcpu, g_r50=qg.recall(0.5), g_r75=qg.recall(0.75),
                         g_n=qg.num_candidates, g_parents=qg.num_parents))
        ours_views[v.frame] = c
    res = {"scene": root.name, "preset": _preset(root), "views": rows}
    if e2e:
        views = [dataclasses.replace(v, masks=ours_views[v.frame]) if v.frame in ours_views else v for v in sc.views]
        ours_scene = dataclasses.replace(sc, views=tuple(views))
        for label, s in (("grounded-sam-like", sc), ("builtin", ours_scene)):
            seg = segment(s)
            ap, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
            res[f"ap_{label}"] = dict(ap25=ap.ap25, ap50=ap.ap50, ap=ap.ap, instances=int(seg.num_instances))
    return res


def sample_bench(root: Path, cfg: BuiltinMaskConfig, overlays: Path | None) -> dict:
    sc = load_scene(root)
    rows = []
    for i, v in enumerate(sc.initial_views):
        t, tc = time.perf_counter(), time.process_time()
        c = builtin_candidates(v, cfg)
        dt, dcpu = time.perf_counter() - t, time.process_time() - tc
        theirs_leaves = leaf_masks(v.masks)
        ours_leaves = leaf_masks(c)
        a = mask_iou_matrix(theirs_leaves, c.masks)
        b = mask_iou_matrix(ours_leaves, v.masks.masks)
        rows.append(dict(frame=v.frame, seconds=dt, cpu_seconds=dcpu, n_ours=len(c), n_theirs=len(v.masks),
                         theirs_leaves=len(theirs_leaves), theirs_matched=int((a.max(1, initial=0) >= 0.5).sum()),
                         ours_leaves=len(ours_leaves), ours_matched=int((b.max(1, initial=0) >= 0.5).sum())))
        if overlays is not None and i == 0:
            from clutt3r_core.io.images import write_png

            overlays.mkdir(parents=True, exist_ok=True)
            img = np.concatenate([overlay(v.rgb, c), overlay(v.rgb, v.masks)], axis=1)
            write_png(overlays / f"{root.parent.name if root.name == 'data' else root.name}_frame{v.frame}.png", img)
    return {"sample": str(root), "size": f"{sc.views[0].camera.width}x{sc.views[0].camera.height}", "views": rows}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="*", default=[])
    ap.add_argument("--samples", default=None, help="folder with sample_seq*/data (skipped when absent)")
    ap.add_argument("--no-e2e", action="store_true")
    ap.add_argument("--overlays", default=None)
    ap.add_argument("--out", default=None)
    ap.add_argument("--set", nargs="*", default=[], help="BuiltinMaskConfig overrides, key=python-literal")
    args = ap.parse_args(argv)
    import ast

    cfg = BuiltinMaskConfig(**{k: ast.literal_eval(v) for k, v in (s.split("=", 1) for s in args.set)})
    print(f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} CPUs; config {cfg}", flush=True)
    results = {"config": dataclasses.asdict(cfg), "scenes": [], "samples": []}
    for s in args.scenes:
        r = scene_bench(Path(s), cfg, not args.no_e2e)
        results["scenes"].append(r)
        v = r["views"]
        line = (f"{r['scene']:28s} {r['preset']:12s} R50 {np.mean([x['r50'] for x in v]):.3f} "
                f"R75 {np.mean([x['r75'] for x in v]):.3f} cands {np.mean([x['n'] for x in v]):5.1f} "
                f"parents {np.mean([x['parents'] / max(x['n'], 1) for x in v]):.2f} "
                f"t {np.median([x['seconds'] for x in v]):.2f}s (cpu {np.median([x['cpu_seconds'] for x in v]):.2f}s) | gsam-like R50 {np.mean([x['g_r50'] for x in v]):.3f} "
                f"R75 {np.mean([x['g_r75'] for x in v]):.3f} cands {np.mean([x['g_n'] for x in v]):.1f}")
        for k in ("ap_grounded-sam-like", "ap_builtin"):
            if k in r:
                line += f" | {k[3:]} AP25/50/AP {r[k]['ap25']:.1f}/{r[k]['ap50']:.1f}/{r[k]['ap']:.1f}"
        print(line, flush=True)
    if args.samples and Path(args.samples).is_dir():
        for name in ("sample_seq1", "sample_seq4"):
            root = Path(args.samples) / name / "data"
            if not root.is_dir():
                continue
            r = sample_bench(root, cfg, Path(args.overlays) if args.overlays else None)
            results["samples"].append(r)
            v = r["views"]
            tl, tm = sum(x["theirs_leaves"] for x in v), sum(x["theirs_matched"] for x in v)
            ol, om = sum(x["ours_leaves"] for x in v), sum(x["ours_matched"] for x in v)
            print(f"{name} ({r['size']}): their leaves matched by ours {tm}/{tl} ({tm / max(tl, 1):.0%}); "
                  f"our leaves matched by theirs {om}/{ol} ({om / max(ol, 1):.0%}); cands ours "
                  f"{np.mean([x['n_ours'] for x in v]):.1f} theirs {np.mean([x['n_theirs'] for x in v]):.1f}; "
                  f"t median {np.median([x['seconds'] for x in v]):.2f}s (cpu {np.median([x['cpu_seconds'] for x in v]):.2f}s)", flush=True)
    elif args.samples:
        print(f"samples folder {args.samples} absent: skipped")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
