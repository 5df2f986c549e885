"""Where the CPU of ``clutt3r segment`` goes, stage by stage, against a baseline commit.

Usage::

    .venv/bin/python benchmarks/bench_core_stages.py [--base 35e98a0] [--current REF] [--runs 3]
        [--scenes hard:0] [--samples sample_seq1] [--work /tmp/clutt3r-bench-command] [--out stages.json]

``benchmarks/bench_command.py`` times the whole command and the core; this one splits them,
in CPU seconds (``time.process_time``: on the project's shared 2-core machine wall times vary
2-5x with the other jobs, CPU time far less). For every scene and both trees (this checkout or
``--current``, and ``--base``; ``git worktree``s under ``--work``, shared with bench_command.py),
``--runs`` fresh processes per tree, alternating, each measuring:

- ``import``: the modules the segment command imports before it reads the scene (the CLI,
  the command, and what its body imports: pipeline, io, runs, visualize, rich);
- ``load_scene``;
- ``first call - warm call``: what the first ``segment()`` of a process pays on top of a warm
  one, mostly lazy imports (threadpoolctl, tqdm, the k-NN library, scipy.sparse.csgraph before
  issue 13's third round);
- every stage of one warm ``segment(scene)`` (``trace.timings``, the pipeline's ``StageClock``
  switched to CPU time in the child), and the warm call as a whole. Since issue 13's fourth
  round the trees and the (light, builtin) embeddings run on a second thread beside the fusion
  and super-voxels: their rows are that thread's own wall seconds, and the CPU of the
  ``pointcloud`` and ``supervoxels`` rows (process-wide ``time.process_time``) includes what
  that thread spent meanwhile; the warm call's total is exact either way. Since session 6 more
  work runs beside: auto's depth disagreement and the voxel position sums (in ``pointcloud``),
  the support's plane fits and every view's mask hits (in ``supervoxels``; the hits' own CPU
  seconds, ``time.thread_time`` on that thread, are added to the ``occupancy`` row);
  ``warm call, main thread`` is the calling thread's own CPU (``time.thread_time``), the part
  no second thread takes over;

medians over the processes, and the current / base ratio. Not a unit test: the numbers depend
on the machine and its load; the instance labels are checked equal (``same``).

Measured 2026-11-30 22:03-22:10 UTC (issue 13, third round: pykdtree k-NN, threaded normal
blocks, own connected components; shared 2-core machine, load average 2.4-6; ``--base 357d37c
--current X``, X = 357d37c with only this round's commits cherry-picked (745d8fb 6a380fb 5e07280
97aa968 684d44d dbcc563), ``--runs 5``), CPU s, base ->
current: hard seed 0: stage pointcloud (fusion + normals) 1.020 -> 0.870, stage supervoxels
0.440 -> 0.298, first call - warm call (lazy imports: scipy.spatial, scipy.sparse.csgraph and
scipy.linalg no more) 0.265 -> 0.122, warm call 1.909 -> 1.521 (0.80), other stages within
noise; sample_seq1: pointcloud 0.900 -> 0.764, supervoxels 0.333 -> 0.265, first - warm 0.296 ->
0.074, warm call 1.587 -> 1.422 (0.90). Instances identical. Left at 640x480 (hard seed 0):
the pointcloud stage 0.87 s (its k-NN query alone about 0.3 s of CPU), import 0.4 s (numpy,
scipy.sparse 0.17-0.19 s for occupancy's two sparse products, tyro, rich), super-voxels
0.3 s, load_scene 0.25 s.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_command import ROOT, _env, _ref_tree, _scenes  # noqa: E402  (this folder's sibling script)

BASE_REF = "35e98a0"  # main before issue 13's fourth speed round (third round: 357d37c)

_HARNESS = """
import json, sys, time
from contextlib import contextmanager
c0 = time.process_time()
import clutt3r_core.cli, clutt3r_core.commands.segment
import rich.console
from clutt3r_core.io import load_scene
from clutt3r_core.io.images import write_png
from clutt3r_core.pipeline import segment
from clutt3r_core.runs import save_run
from clutt3r_core.visualize import overview_sheet
c1 = time.process_time()
import clutt3r_core.segmentation.trace as trace

@contextmanager
def _cpu_stage(self, stage):  # StageClock.__call__ in CPU seconds
    t0 = time.process_time()
    try:
        yield
    finally:
        self.items.append(trace.StageTiming(stage, time.process_time() - t0))

trace.StageClock.__call__ = _cpu_stage
scene = load_scene(sys.argv[1])
c2 = time.process_time()
segment(scene)
c3, t3 = time.process_time(), time.thread_time()
seg = segment(scene)
c4, t4 = time.process_time(), time.thread_time()
out = {"import": c1 - c0, "load_scene": c2 - c1, "first call - warm call": (c3 - c2) - (c4 - c3),
       "warm call": c4 - c3, "warm call, main thread": t4 - t3,
       "stages": {t.stage: t.seconds for t in seg.trace.timings},
       "instance": seg.instance.tolist()}
print("STAGES=" + json.dumps(out))
"""


def _measure(tree: Path, scene: Path) -> dict:
    r = subprocess.run([sys.executable, "-c", _HARNESS, str(scene)], cwd=tree, env=_env(tree),
                       capture_output=True, text=True, timeout=600)
    line = [x for x in r.stdout.splitlines() if x.startswith("STAGES=")]
    if r.returncode != 0 or not line:
        raise SystemExit(f"{tree}: harness failed ({r.returncode}):\n{r.stderr[-3000:]}")
    return json.loads(line[-1][len("STAGES="):])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default=BASE_REF, help="git ref of the baseline tree")
    ap.add_argument("--current", default=None, help="git ref of the current tree (default: this checkout)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--work", type=Path, default=Path("/tmp/clutt3r-bench-command"))
    ap.add_argument("--scenes", nargs="*", default=["hard:0"], help="generated scenes, PRESET:SEED")
    ap.add_argument("--samples", nargs="*", default=["sample_seq1"])
    ap.add_argument("--out", type=Path, default=None, help="JSON file of the raw numbers")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    trees = {"base": _ref_tree(args.base, args.work),
             "current": _ref_tree(args.current, args.work) if args.current else ROOT}
    raw: dict = {}
    lines = ["| scene | CPU s (median) | base | current | current / base |", "|---|---|---|---|---|"]
    for label, _, folder in _scenes(args, args.work):
        runs: dict[str, list[dict]] = {"base": [], "current": []}
        for i in range(args.runs):
            for name in ("base", "current"):  # alternating: both see the same load
                m = _measure(trees[name], folder)
                runs[name].append(m)
                print(f"{label} {name} run {i}: warm {m['warm call']:.2f} s CPU, import {m['import']:.2f} s",
                      file=sys.stderr)
        same = all(b["instance"] == c["instance"] for b, c in zip(runs["base"], runs["current"]))
        rows = ["import", "load_scene", "first call - warm call"]
        stages = list(runs["current"][0]["stages"])
        rows += [f"stage {s}" for s in stages] + ["warm call", "warm call, main thread"]

        def med(name: str, row: str) -> float:
            def get(m: dict) -> float:
                return m["stages"].get(row[6:], float("nan")) if row.startswith("stage ") else m[row]
            return statistics.median(get(m) for m in runs[name])

        raw[label] = {n: [{k: v for k, v in m.items() if k != "instance"} for m in r] for n, r in runs.items()}
        for row in rows:
            b, c = med("base", row), med("current", row)
            ratio = f"{c / b:.2f}" if b > 0 else "–"
            lines.append(f"| {label} | {row} | {b:.3f} | {c:.3f} | {ratio} |")
        lines.append(f"| {label} | instances identical to base | {same} | | |")
    print("\n".join(lines))
    if args.out:
        args.out.write_text(json.dumps(raw, indent=1))


if __name__ == "__main__":
    main()
