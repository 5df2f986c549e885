"""Leave-one-out ablation of our additions over the paper's text (issue 13), with real-sample agreement.

Usage:
    .venv/bin/python benchmarks/bench_ablation.py [--seed 100] [--workers 2] [--paper-with]
        [--samples /work/shared/data/clutt3r-samples] [--out docs/benchmark/ablation]
        [--markdown docs/benchmark/ablation.md] [--cache .bench-cache]

What it runs:

- AP (the benchmark runner, ``clutt3r bench``'s jobs and cache): one generated scene per
  difficulty (seed ``--seed``; 8 views, 640x480, Grounded-SAM-like candidates, RealSense-like
  depth noise: ``SynthConfig(depth_noise="realsense")``), for ``ours``, ``paper``, every
  ``ours-no-<key>`` (ours with one addition off) and, with ``--paper-with``, every
  ``paper-with-<key>`` (``clutt3r_core.evaluation.methods.ABLATION_METHODS``; about doubles
  the AP jobs);
- leaf-pair agreement (F1) with the original method's ``instance_tree.json`` on the real
  samples that are present (``clutt3r_core.segmentation.compare``), for ``ours``, ``paper``
  and every ``ours-no-<key>`` (the ``paper-with`` rows are AP only: the paper preset fuses
  1080p views without a pixel stride, which takes minutes per sample on 2 cores).

Writes ``OUT/ablation.json`` (every job result and F1) and the Markdown tables
(``report.ablation_tables``) to ``--markdown``. Finished AP jobs are cached like
``clutt3r bench``'s (content hash of scene, config and code), and so is each F1
(``CACHE/agreement/<hash>.json``, same kind of key), so a second run with ``--paper-with``
only adds the new jobs.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _agreement(args: tuple[str, str, str]) -> tuple[str, str, float, float, bool]:
    """(method, sample, F1, seconds, cached) of one segmentation of a real sample."""
    method, sample, cache = args
    from clutt3r_core.evaluation.jobs import _sha, code_version
    from clutt3r_core.evaluation.methods import method_config

    cfg = method_config(method)
    key = Path(cache) / "agreement" / (_sha([method, asdict(cfg), str(Path(sample).resolve()), code_version()]) + ".json")
    if key.is_file():
        d = json.loads(key.read_text())
        return method, Path(sample).name, d["f1"], d["seconds"], True
    from clutt3r_core.io import load_scene
    from clutt3r_core.pipeline import instance_tree_json, segment
    from clutt3r_core.segmentation.compare import leaf_pair_agreement

    d = Path(sample) / "data"
    t0 = time.perf_counter()
    seg = segment(load_scene(d), cfg)
    f1 = leaf_pair_agreement(instance_tree_json(seg), d / "instance_tree.json").f1
    sec = time.perf_counter() - t0
    key.parent.mkdir(parents=True, exist_ok=True)
    key.write_text(json.dumps({"f1": f1, "seconds": sec}))
    return method, Path(sample).name, f1, sec, False


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=100)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--paper-with", action="store_true", help="also the paper-with-<key> rows (AP only)")
    ap.add_argument("--only", nargs="*", default=None, metavar="KEY",
                    help="only these additions (config.ADDITIONS keys), besides ours and paper")
    ap.add_argument("--samples", type=Path, default=Path("/work/shared/data/clutt3r-samples"))
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "benchmark" / "ablation")
    ap.add_argument("--markdown", type=Path, default=ROOT / "docs" / "benchmark" / "ablation.md")
    ap.add_argument("--cache", type=Path, default=ROOT / ".bench-cache")
    a = ap.parse_args()

    from clutt3r_core.evaluation.jobs import Setting, _sha, synth_version
    from clutt3r_core.evaluation.methods import ABLATION_METHODS
    from clutt3r_core.evaluation.report import ablation_tables
    from clutt3r_core.evaluation.runner import ProcessExecutor, SerialExecutor, plan_jobs, run_benchmark
    from clutt3r_core.evaluation.jobs import SceneSpec
    from clutt3r_core.synth.generator import SynthConfig

    t0 = time.perf_counter()
    scenes = []
    for d in ("easy", "intermediate", "hard"):
        cfg = asdict(SynthConfig(seed=a.seed, preset=d, views=8, width=640, height=480,
                                 mask_noise="grounded-sam-like", depth_noise="realsense"))
        scenes.append(SceneSpec(f"synth_{d}_{a.seed:04d}_realsense", d, synth=cfg, identity=_sha([cfg, synth_version()])))
    def wanted(m: str) -> bool:
        key = m.removeprefix("ours-no-").removeprefix("paper-with-")
        return (a.paper_with or m.startswith("ours-no-")) and (a.only is None or key in a.only)

    methods = ["ours", "paper"] + [m for m in ABLATION_METHODS if wanted(m)]
    jobs = plan_jobs(scenes, methods, [Setting()], a.cache.resolve())
    ex = SerialExecutor() if a.workers <= 1 else ProcessExecutor(a.workers)
    results = run_benchmark(jobs, ex, progress=True)
    t_ap = time.perf_counter() - t0

    samples = [p for p in (a.samples / "sample_seq1", a.samples / "sample_seq4") if (p / "data" / "instance_tree.json").is_file()]
    if not samples:
        print(f"no real samples under {a.samples}: agreement columns left out", file=sys.stderr)
    ag_methods = [m for m in methods if not m.startswith("paper-with-")]
    todo = [(m, str(s), str(a.cache.resolve())) for m in ag_methods for s in samples]
    agreement: dict[str, dict[str, float]] = {}
    seconds = {}
    n_cached = 0
    import multiprocessing as mp

    # spawn, not fork: the jobs above ran in this process, and a forked child inherits pykdtree's
    # OpenMP (libgomp) state without its threads, so its first parallel k-NN query waits forever
    # (seen: the ablation hung in rim_apart's query after a --workers 1 run)
    with ProcessPoolExecutor(max_workers=max(1, a.workers), mp_context=mp.get_context("spawn")) as pool:
        for m, s, f1, sec, hit in pool.map(_agreement, todo):
            agreement.setdefault(m, {})[s] = f1
            seconds[f"{m}/{s}"] = sec
            n_cached += hit
            print(f"{m:32s} {s}: F1 {f1:.3f} ({sec:.1f} s{', cached' if hit else ''})", file=sys.stderr)
    elapsed = time.perf_counter() - t0

    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / "ablation.json").write_text(json.dumps({
        "scenes": [s.name for s in scenes], "seconds_ap": t_ap, "seconds_total": elapsed,
        "agreement": agreement, "agreement_seconds": seconds, "results": [r.to_json() for r in results]}, indent=1))
    from clutt3r_core.evaluation.jobs import code_version

    cmd = ".venv/bin/python benchmarks/bench_ablation.py " + " ".join(sys.argv[1:])
    load = os.getloadavg()[0]
    md = ["# Leave-one-out ablation of our additions over the paper", "",
          "Reproduce:", "", "```", cmd.strip(), "```", "",
          f"Wall time of this run: {elapsed / 60:.1f} min on {os.cpu_count()} CPUs with {a.workers} workers "
          f"(load average {load:.0f} at the end) for {len(results)} AP jobs ({sum(r.cached for r in results)} from "
          f"cache) and {len(todo)} real-sample segmentations ({n_cached} from cache). Code version `{code_version()}`. "
          "Scenes: one per difficulty, seed "
          f"{a.seed}, 8 views at 640x480, Grounded-SAM-like candidates, RealSense-like depth noise.", "",
          ablation_tables(results, agreement)]
    a.markdown.parent.mkdir(parents=True, exist_ok=True)
    a.markdown.write_text("\n".join(md))
    print(f"{a.markdown} ({elapsed / 60:.1f} min)")


if __name__ == "__main__":
    main()
