"""Benchmark text queries (issue 17): top-1 / top-3 on generated scenes, confidence, time.

Usage:
    .venv/bin/python benchmarks/bench_query.py [--work /tmp/clutt3r-bench-query]
        [--presets easy intermediate hard] [--seeds 10 11] [--backend imagenet-minilm]
        [--sweep] [--cli] [--out docs/benchmark/query.json]

For every generated scene (``clutt3r synth`` with the given preset and seed, 8 views,
grounded-sam-like masks) it segments with the default preset, opens the run for queries
(``RunQuery.open``: embeds the masks once, cached in the run folder, so reruns and
``--sweep`` only re-score), and asks, for every ground-truth object that some instance
covers (3D IoU >= 0.5 on the 10 mm grid):

* ``name``: its everyday category name ("mustard bottle", "banana");
* ``colour + name``: its body colour word and the name ("yellow mustard bottle");
* ``absent``: names of generator objects that are NOT in the scene (up to 5 per scene),
  to measure how often ``confident`` is wrongly true.

A query is right when the target instance's best-overlapping GT object has the queried
category (two cups: either counts). Top-3: such an instance is among the first three.
Chance: mean over queries of (instances of that category) / (instances).
It also reports the Table II semantic 3D IoU of the target's points with the GT voxels of
the queried category (``evaluation.metrics.semantic_iou``), time per query in process
(models loaded, evidence cached), time to embed a run, and with ``--cli`` the wall time
of whole ``clutt3r query`` processes.

Not a unit test: the numbers depend on the machine's load.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def prepare(work: Path, preset: str, seed: int) -> tuple[Path, Path]:
    from clutt3r_core.io import load_scene
    from clutt3r_core.pipeline import segment
    from clutt3r_core.runs import is_run_folder, save_run
    from clutt3r_core.synth import SynthConfig, generate, write_synth_scene

    scene_dir = work / f"{preset}-{seed}" / "scene"
    run_dir = work / f"{preset}-{seed}" / "run"
    if not (scene_dir / "transforms.json").is_file():
        res = generate(SynthConfig(seed=seed, preset=preset, views=8))
        write_synth_scene(res.scene, scene_dir, info=res.info, contact_sheet=False)
    if not is_run_folder(run_dir):
        sc = load_scene(scene_dir)
        save_run(segment(sc), run_dir, scene_root=scene_dir)
    return scene_dir, run_dir


def gt_of_instances(seg, gt) -> tuple[np.ndarray, np.ndarray]:
    """(best GT object per instance (I,), best IoU (I,)), and which GT objects are covered."""
    from clutt3r_core.evaluation.metrics import instance_iou, voxelize_labels

    pv = voxelize_labels(seg.points, seg.instance)
    gv = voxelize_labels(gt.points, gt.point_labels)
    iou, pid, gid, _ = instance_iou(pv, gv)
    best = np.full(seg.num_instances, -1, np.int64)
    best_iou = np.zeros(seg.num_instances)
    for r, p in enumerate(pid):
        if iou.shape[1]:
            best[p] = gid[int(np.argmax(iou[r]))]
            best_iou[p] = iou[r].max()
    covered = {int(gid[c]) for c in range(iou.shape[1]) if iou[:, c].max() >= 0.5} if iou.size else set()
    return best, best_iou, covered


def queries_for(scene, covered: set[int], rng) -> list[tuple[str, str, str]]:
    """(kind, text, category) triples."""
    from clutt3r_core.language.colors import color_name_of
    from clutt3r_core.synth.objects import REGISTRY

    out = []
    cats = {o.category for o in scene.ground_truth.objects}
    for o in scene.ground_truth.objects:
        if o.id not in covered:
            continue
        out.append(("name", o.category, o.category))
        if o.color is not None:
            out.append(("colour + name", f"{color_name_of(o.color)} {o.category}", o.category))
    absent = sorted({s.category for s in REGISTRY} - cats)
    for c in rng.choice(absent, size=min(5, len(absent)), replace=False):
        out.append(("absent", str(c), str(c)))
    return out


def evaluate(cases, config, semantic: bool = True) -> dict:
    """cases: list of (rq, seg, scene, best_gt, queries). Returns metrics per kind."""
    from clutt3r_core.evaluation.metrics import semantic_iou

    per: dict[str, dict[str, list]] = {}
    times = []
    for rq, seg, scene, best, queries in cases:
        rq = replace(rq, config=config)
        cat_of_inst = np.array([scene.ground_truth.objects[b].category if b >= 0 else "" for b in best], dtype=object)
        masks, cats = [], []
        for kind, text, cat in queries:
            res = rq.query(text)
            times.append(res.time_s)
            d = per.setdefault(kind, {"top1": [], "top3": [], "chance": [], "confident": [], "conf_right": []})
            right = res.target is not None and cat_of_inst[res.target] == cat
            d["top1"].append(right)
            d["top3"].append(any(cat_of_inst[i] == cat for i in res.ranking[:3]))
            d["chance"].append(float(np.mean(cat_of_inst == cat)) if len(cat_of_inst) else 0.0)
            d["confident"].append(res.confident)
            d["conf_right"].append(res.confident and right)
            if kind != "absent" and res.target is not None:
                masks.append(seg.instance == res.target)
                cats.append(cat)
        if masks and semantic:
            s = semantic_iou(seg.points, masks, cats, scene.ground_truth)
            per.setdefault("_semantic_iou", {"iou": []})["iou"].extend(x.iou for x in s.per_query)
    out = {}
    for kind, d in per.items():
        if kind == "_semantic_iou":
            out["semantic_iou"] = float(np.mean(d["iou"]))
            continue
        n = len(d["top1"])
        conf = sum(d["confident"])
        out[kind] = {
            "n": n, "top1": float(np.mean(d["top1"])), "top3": float(np.mean(d["top3"])),
            "chance": float(np.mean(d["chance"])), "confident_rate": conf / n,
            "precision_when_confident": (sum(d["conf_right"]) / conf) if conf else float("nan"),
        }
    out["query_ms_median"] = 1e3 * statistics.median(times) if times else float("nan")
    out["query_ms_p90"] = 1e3 * float(np.percentile(times, 90)) if times else float("nan")
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/clutt3r-bench-query"))
    ap.add_argument("--presets", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[10, 11])
    ap.add_argument("--backend", default="imagenet-minilm")
    ap.add_argument("--sweep", action="store_true", help="grid over temperature and colour weight")
    ap.add_argument("--margins", action="store_true", help="sweep only QueryConfig.confident_margin")
    ap.add_argument("--cli", action="store_true", help="time whole `clutt3r query` processes")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from clutt3r_core.io import load_scene
    from clutt3r_core.query import QueryConfig, RunQuery, create_grounder
    from clutt3r_core.query.evidence import CACHE_NAME
    from clutt3r_core.runs import load_run

    t = time.perf_counter()
    grounder = create_grounder(args.backend)
    grounder.embed_text(["warm up"])
    load_s = time.perf_counter() - t
    rng = np.random.default_rng(0)
    cases, embed_s, n_masks = [], [], []
    for preset in args.presets:
        for seed in args.seeds:
            scene_dir, run_dir = prepare(args.work, preset, seed)
            fresh = not (run_dir / CACHE_NAME).is_file()
            t = time.perf_counter()
            rq = RunQuery.open(run_dir, grounder=grounder)
            if fresh:
                embed_s.append(time.perf_counter() - t)
                n_masks.append(len(rq.evidence.nodes))
            seg = load_run(run_dir)
            scene = load_scene(scene_dir)
            best, _, covered = gt_of_instances(seg, scene.ground_truth)
            cases.append((rq, seg, scene, best, queries_for(scene, covered, rng)))
            print(f"{preset}-{seed}: {seg.num_instances} instances, {len(covered)}/{len(scene.ground_truth.objects)} objects covered",
                  file=sys.stderr)
    report = {"backend": args.backend, "scenes": [f"{p}-{s}" for p in args.presets for s in args.seeds],
              "model_load_s": load_s, "default": evaluate(cases, QueryConfig())}
    print(json.dumps(report["default"]), file=sys.stderr)
    if embed_s:
        report["embed_run_s"] = {"mean": float(np.mean(embed_s)), "masks_mean": float(np.mean(n_masks)),
                                 "ms_per_mask": 1e3 * float(np.sum(embed_s) / max(np.sum(n_masks), 1))}
    if args.sweep:
        grid = []
        # the sweep re-scores the same phrases many times: embed each once
        memo: dict[str, np.ndarray] = {}
        embed = grounder.embed_text
    
        def embed_memo(texts):
            for x in texts:
                if x not in memo:
                    memo[x] = embed([x])[0]
            return np.stack([memo[x] for x in texts])
    
        grounder.embed_text = embed_memo
        # ranking settings first (the margin only changes `confident`), then the margin at the default
        for center in (True, False):
            for temp in (0.02, 0.05, 0.1):
                for cw in (1.0, 2.0, 3.0):
                    for gate in (0.0, 0.45):
                        cfg = QueryConfig(temperature=temp, color_weight=cw, center=center, name_gate=gate)
                        r = evaluate(cases, cfg, semantic=False)
                        grid.append({"center": center, "temperature": temp, "color_weight": cw, "gate": gate,
                                     **{k: r[k] for k in ("name", "colour + name", "absent") if k in r}})
                        print(json.dumps(grid[-1]), file=sys.stderr)
        for margin in (0.25, 0.5, 0.75, 1.0, 1.5):
            r = evaluate(cases, QueryConfig(confident_margin=margin), semantic=False)
            grid.append({"margin": margin, **{k: r[k] for k in ("name", "colour + name", "absent") if k in r}})
            print(json.dumps(grid[-1]), file=sys.stderr)
        report["sweep"] = grid
    if args.margins:
        rows = []
        for margin in (0.25, 0.5, 0.75, 1.0, 1.25, 1.5):
            r = evaluate(cases, QueryConfig(confident_margin=margin), semantic=False)
            rows.append({"margin": margin, **{k: r[k] for k in ("name", "colour + name", "absent") if k in r}})
            print(json.dumps(rows[-1]), file=sys.stderr)
        report["margins"] = rows
    if args.cli:
        run_dir = args.work / f"{args.presets[0]}-{args.seeds[0]}" / "run"
        walls = []
        for text in ("the red apple", "mug", "yellow mustard bottle"):
            t = time.perf_counter()
            subprocess.run([str(ROOT / ".venv/bin/clutt3r"), "query", str(run_dir), text, "--json"], check=True,
                           capture_output=True)
            walls.append(time.perf_counter() - t)
        report["cli_process_s"] = {"median": statistics.median(walls), "all": walls}
    text = json.dumps(report, indent=1)
    print(text)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)


if __name__ == "__main__":
    main()
