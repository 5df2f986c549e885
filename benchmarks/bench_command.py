"""Benchmark ``clutt3r segment`` as a whole process, and the core in-process, against a baseline commit.

Usage::

    .venv/bin/python benchmarks/bench_command.py [--base 35e98a0] [--current REF] [--runs 3] [--work /tmp/clutt3r-bench-command]
        [--scenes hard:0] [--samples sample_seq4] [--no-base] [--outside] [--out results.json]

Issue 13 measured the whole command, not only the core: on a hard 640x480 8-view scene it
took 4.1 s (1.9 s importing: the command table imported every command's module and the
normals imported open3d, whose package init loads its plotly/dash visualisation), and
on sample_seq4 (1920x1080, 8 views) 9.2 s with a 957 MiB peak. Targets, as whole processes:
<= 2 s at 640x480, <= 4 s and <= 600 MiB at 1920x1080; the core <= 1 s at 640x480.

For every scene (generated ones, ``clutt3r synth --preset P --seed S``, cached under
``--work``; then the real samples that are present) and for both code trees (this checkout
and ``--base``, checked out with ``git worktree add`` under ``--work``, run with this
checkout's virtual environment and ``PYTHONPATH`` set to the tree), it measures:

- whole: ``python -m clutt3r_core.cli segment SCENE --out RUN`` (what the ``clutt3r``
  script runs) as a subprocess: wall time, CPU time (user + sys) and peak resident set
  (``os.wait4``'s ``ru_maxrss`` of that child), median over ``--runs`` (max for the RSS);
  base and current runs alternate, so both see the same machine load;
- core: ``segment(load_scene(SCENE))`` in ``--runs`` fresh processes per tree, alternating
  like the whole command: each makes a first call (it pays the lazy imports: scipy.spatial,
  and open3d before dfdac67) and one warm call, wall, CPU and the calling thread's own CPU
  (``time.thread_time``: what no second thread takes over), and from that an estimate of the
  wall on an idle 2-core machine (calling thread + half the normals' CPU, whose blocks run on
  two threads while it waits; session 6); medians over the processes; mask generation is not
  involved (the scenes have mask candidates);
- outside (``--outside``): the whole command's CPU minus what it spent inside ``pipeline.segment``,
  in ``--runs`` more processes per tree, alternating; with paired current / base ratios (each
  current run against the base run just before it), as for the whole command's wall and CPU;
- same: whether the two trees' run folders hold identical arrays (``instances.npz``,
  ``cloud.npz``, ``trace/trace.npz``; NaN equal to NaN).

CPU time is the fairer number on a loaded machine (the segment command is mostly one
thread): on the project's shared 2-core machine wall times vary 2-3x with other jobs.
Prints a markdown table with current / base ratios; ``--out`` writes the raw numbers.

Measured 2026-11-30 (shared 2-core machine, load average 10-13, so wall times are 3-5x an
idle machine's; ``--current`` = dfdac67 plus the speed commits only), current / base:
hard 640x480 whole command CPU 7.02 / 7.53 s, peak RSS 332 / 435 MiB, warm core CPU 3.61 /
3.02 s; sample_seq4 whole command CPU 14.32 / 15.25 s, peak RSS 649 / 826 MiB, warm core CPU
4.93 / 4.13 s; instances identical. Table and reading: docs/benchmark.md, "Whole command".

Second round, measured 2026-11-30 19:47-19:51 UTC against 2bca0bb (``--current`` = 2bca0bb
plus the second round's speed commits only; shared 2-core machine, load average 3.4-5.6),
median of 3, current / base: hard 640x480 whole command wall 3.35 / 3.94 s (0.85), CPU
3.84 / 5.72 s (0.67), peak RSS 333 / 336 MiB; warm core wall 1.98 / 2.25 s, CPU 2.20 /
3.13 s (0.70); sample_seq4 whole command wall 7.57 / 13.29 s (0.57), CPU 7.57 / 13.63 s
(0.56), peak RSS 662 / 677 MiB; warm core CPU 3.12 / 3.86 s. Instances, cloud.npz and
overview.png identical. What made the difference: overview.png's splat (1 s of CPU per
1080p view before), numpy's BLAS on one thread (its idle threads spun: ~1 s of CPU per
run), the super-voxel graph reusing the normals' k-NN table, npz files at zlib level 1.
Still missed: 2 s and 1 s at 640x480, 4 s and 600 MiB at 1080p (the 1080p masks alone are
240 MiB of bool stacks; docs/benchmark.md, "Whole command", second round).
Third round, measured 2026-11-30 21:56-22:02 UTC against 357d37c (``--current`` = 357d37c plus
the third round's commits only; shared 2-core machine, load average 3-12), median of 3, current
/ base: sample_seq4 whole command CPU 4.88 / 6.89 s (0.71), wall 6.73 / 8.66 s, peak RSS 423 /
655 MiB (0.65; the three runs 396-423); warm core CPU 1.87 / 2.80 s; hard 640x480 whole command
CPU 3.15 / 3.29 s, peak RSS 305 / 333 MiB. Instances identical (and cloud, trace arrays:
checked separately on seq4, seq1, hard 0, easy 1). What made the difference: mask candidates
stored as a per-pixel mask-set code image (2 MiB per 1080p view instead of 2 MiB per mask;
trees, occupancy, histograms and duplicates read the codes), Sub-filtered mask PNGs decoded
from their value changes, OpenCV histograms for the appearance descriptor, and one loader
thread per core (each extra thread kept its own malloc arena: 530 MiB peak with 8 threads,
390 with 2). 600 MiB is met; 4 s is not on this machine (docs/benchmark.md, third round).
Fourth round, measured 2026-12-01 00:29-00:35 UTC against 35e98a0 (``--current 2cd687e`` =
35e98a0 plus the fourth round's commits only; shared 2-core machine at load average 6-10, wall
2-4x an idle machine's), median of 3, current / base: hard 640x480 whole command CPU 2.90 /
2.90 s, peak RSS 312 / 306 MiB, warm core CPU 1.74 / 1.75 s (no change at 640x480);
sample_seq4 whole command CPU 4.77 / 5.37 s (0.89), peak RSS 508 / 467 MiB (a second thread's
malloc arena), warm core CPU 2.30 / 2.38 s, load_scene CPU 1.34 / 1.58 s (bench_core_stages.py).
Identical arrays on the 8 check scenes. What made the difference: zlib-ng inflating the mask
PNGs and run-based set compaction of the mask codes; the later imports beside the loading, the
trees and embeddings beside the fusion and overview.png beside save_run save wall time only
where a core is idle, which this machine could not show (docs/benchmark.md, "Whole command",
fourth round).
Session 6 (the core under 1 s), measured 2026-12-01 03:24-03:29 UTC against 6cc7f43 (load
5-10), median of 5: hard 640x480 core warm CPU 1.52 / 1.70 s (within the spread), calling
thread's CPU 0.96 -> 0.71 s, idle-2-core estimate 1.23 -> 1.06 (1.05 -> 0.86 in a run where the
base's estimate matched its quiet measurement); whole command CPU 2.71 -> 2.54 s, peak 318 -> 283
MiB; sample_seq4 peak 522 / 536 MiB. Identical arrays (docs/benchmark.md, "Session 6").
Session 7 (the whole command), measured 2026-12-01 05:11-05:16 UTC against 88dd1b6 (load 4.5-10,
``--runs 5 --outside``): CPU outside the core (``--outside``) hard 640x480 1.054 -> 0.878 s (paired
0.91, every pair lower), sample_seq4 2.71 -> 2.30 s (0.85); sample_seq4 peak median 516 -> 492 MiB;
identical arrays. Wall could not be compared: the machine gave no second core (docs/benchmark.md,
"Session 7").
Base and ``--current`` checkouts are ``git worktree``s under ``--work``, kept for the next run
(``git worktree remove`` them when done).

The old checkout's CLI is started through a small harness that skips entry-point commands
(``clutt3r.commands``, from the installed package metadata) whose function the old tree
does not have yet; their modules are still imported, as the old ``clutt3r`` would.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLES = ROOT.parent / "shared" / "data" / "clutt3r-samples"
# main at the start of the fourth round of issue-13 work (zlib-ng masks, threads beside the
# fusion and the saving); the third round's base was 357d37c (before the 1080p masks as code
# images), the second round's 2bca0bb (before the overview splat, BLAS threads, shared k-NN),
# the first round's dfdac67 (before the lazy CLI and open3d-free normals)
BASE_REF = "35e98a0"
TARGETS = {  # whole-process wall s, core wall s, peak RSS MiB (issue 13)
    "generated": (2.0, 1.0, None),
    "sample_seq4": (4.0, None, 600.0),
}

_CLI_HARNESS = """
import sys
import clutt3r_core.cli as cli
_load = cli._load
def _tolerant(target):
    try:
        return _load(target)
    except AttributeError:  # an installed entry point that this (older) tree does not define
        return None
cli._load = _tolerant
cli.main()  # the process's own command line (sys.argv), as the clutt3r script calls it
"""

# the whole command with the core's CPU taken out: process CPU minus what the process spent
# inside pipeline.segment (the other threads are idle then: the loading and the preparing
# thread have finished, the drawing has not begun). The core's CPU is most of the whole and
# its run-to-run spread on a loaded machine is larger than what the command around it costs,
# so this is the number that shows a change outside the core. pipeline is imported before
# main() to wrap it (the command would import it a little later: the same modules, the same CPU).
_OUTSIDE_HARNESS = """
import sys, time
import clutt3r_core.pipeline as pl
_seg, inside = pl.segment, [0.0]
def _timed(*a, **k):
    c = time.process_time()
    try:
        return _seg(*a, **k)
    finally:
        inside[0] += time.process_time() - c
pl.segment = _timed
import clutt3r_core.cli as cli
try:
    cli.main(sys.argv[1:])
finally:
    sys.stdout.write("OUTSIDE=%.4f\\n" % (time.process_time() - inside[0]))
"""

_CORE_HARNESS = """
import json, sys, time
from clutt3r_core.io import load_scene
from clutt3r_core.pipeline import segment
import clutt3r_core.pointcloud as pc
normals = [0.0]
if hasattr(pc, "estimate_normals"):  # the normals' CPU (process-wide: their blocks run on threads)
    _estimate = pc.estimate_normals
    def _timed(*a, **k):
        c = time.process_time()
        try:
            return _estimate(*a, **k)
        finally:
            normals[0] += time.process_time() - c
    pc.estimate_normals = _timed
scene = load_scene(sys.argv[1])
out = []
for _ in range(int(sys.argv[2]) + 1):
    normals[0] = 0.0
    w, c, t = time.perf_counter(), time.process_time(), time.thread_time()
    segment(scene)
    out.append((time.perf_counter() - w, time.process_time() - c, time.thread_time() - t, normals[0]))
print("CORE=" + json.dumps(out))
"""


def _run_child(cmd: list[str], cwd: Path, env: dict) -> dict:
    """Like subprocess.run, but with the child's own rusage (os.wait4), not the sum of all children."""
    r, w = os.pipe()
    t0 = time.perf_counter()
    pid = os.fork()
    if pid == 0:  # child: stdout/stderr to the pipe, then exec
        try:
            os.close(r)
            os.dup2(w, 1)
            os.dup2(w, 2)
            os.chdir(cwd)
            os.execve(cmd[0], cmd, env)
        finally:
            os._exit(127)
    os.close(w)
    chunks = []
    while True:
        b = os.read(r, 1 << 16)
        if not b:
            break
        chunks.append(b)
    os.close(r)
    _, status, ru = os.wait4(pid, 0)
    wall = time.perf_counter() - t0
    return {
        "rc": os.waitstatus_to_exitcode(status),
        "wall": wall,
        "cpu": ru.ru_utime + ru.ru_stime,
        "rss_mib": ru.ru_maxrss / 1024.0,  # Linux: KiB
        "output": b"".join(chunks).decode(errors="replace"),
    }


def _env(tree: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("CLUTT3R_DEBUG",)}
    env["PYTHONPATH"] = str(tree)
    env["PYTHONDONTWRITEBYTECODE"] = "1"
    return env


def _ref_tree(ref: str, work: Path) -> Path:
    """A checkout of ``ref`` under ``work`` (``git worktree add``, kept for the next run)."""
    sha = subprocess.run(["git", "rev-parse", ref], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    tree = work / f"tree-{sha[:12]}"
    if not (tree / "clutt3r_core").is_dir():
        subprocess.run(["git", "worktree", "add", "--detach", str(tree), sha], cwd=ROOT, check=True,
                       capture_output=True)
    if not (tree / "clutt3r_core" / "__pycache__").is_dir():
        # bytecode, as an installed package has it: the children run with PYTHONDONTWRITEBYTECODE,
        # so without it every process compiled every module from source (0.14 s of CPU each)
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "clutt3r_core")], check=True,
                       capture_output=True)
    return tree


def _scenes(args, work: Path) -> list[tuple[str, str, Path]]:
    """(label, kind for the targets, folder) of every scene to run; generates missing ones."""
    out = []
    for spec in args.scenes:
        preset, _, seed = spec.partition(":")
        folder = work / "scenes" / f"{preset}_{seed or 0}"
        if not (folder / "transforms.json").is_file():
            subprocess.run([sys.executable, "-m", "clutt3r_core.cli", "synth", "--out", str(folder),
                            "--preset", preset, "--seed", seed or "0"], cwd=ROOT, check=True, env=_env(ROOT))
        out.append((f"{preset} seed {seed or 0} (640x480, 8 views)", "generated", folder))
    for name in args.samples:
        folder = SAMPLES / name
        if folder.is_dir():
            out.append((f"{name} (real)", name, folder))
        else:
            print(f"skipped {name}: {folder} is absent", file=sys.stderr)
    return out


_COMPARED = ("instances.npz", "cloud.npz", "trace/trace.npz")


def _same_outputs(a: Path, b: Path) -> bool | None:
    """Whether two run folders hold the same arrays in ``_COMPARED`` (NaN equal to NaN; a file
    that only one of them has is skipped: older trees wrote fewer); None if neither has
    instances.npz."""
    import numpy as np

    if not (a / "instances.npz").is_file() or not (b / "instances.npz").is_file():
        return None
    for rel in _COMPARED:
        if not (a / rel).is_file() or not (b / rel).is_file():
            continue
        with np.load(a / rel) as x, np.load(b / rel) as y:
            if sorted(x.files) != sorted(y.files):
                return False
            for k in x.files:
                u, v = x[k], y[k]
                if u.dtype != v.dtype or not np.array_equal(u, v, equal_nan=u.dtype.kind in "fc"):
                    return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--base", default=BASE_REF, help="git ref of the baseline tree")
    ap.add_argument("--no-base", action="store_true", help="measure this checkout only")
    ap.add_argument("--current", default=None,
                    help="git ref to measure as 'current' instead of this working tree (e.g. to leave out "
                         "uncommitted work of others)")
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--work", type=Path, default=Path("/tmp/clutt3r-bench-command"))
    ap.add_argument("--scenes", nargs="*", default=["hard:0"], help="generated scenes, PRESET:SEED")
    ap.add_argument("--samples", nargs="*", default=["sample_seq4"])
    ap.add_argument("--no-core", action="store_true", help="whole processes only")
    ap.add_argument("--outside", action="store_true",
                    help="also: the whole command's CPU outside pipeline.segment (--runs more processes per tree)")
    ap.add_argument("--out", type=Path, default=None, help="JSON file of the raw numbers")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    current = _ref_tree(args.current, args.work) if args.current else ROOT
    if not args.current:
        # the children run with PYTHONDONTWRITEBYTECODE: without this, every module edited since
        # its bytecode was written is compiled again in every process (the base tree is compiled)
        subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "clutt3r_core")], check=True,
                       capture_output=True)
    load_start = os.getloadavg()
    trees = {"current": current}
    if not args.no_base:
        trees = {"base": _ref_tree(args.base, args.work), "current": current}
    py = sys.executable
    results = []
    for label, kind, folder in _scenes(args, args.work):
        row = {"scene": label, "kind": kind, "whole": {t: [] for t in trees}, "core": {}}
        for i in range(args.runs):
            for t, tree in trees.items():  # alternate the trees: same load for both
                run_dir = args.work / "runs" / f"{folder.name}_{t}"
                shutil.rmtree(run_dir, ignore_errors=True)
                r = _run_child([py, "-c", _CLI_HARNESS, "segment", str(folder), "--out", str(run_dir)], tree, _env(tree))
                if r["rc"] != 0:
                    raise SystemExit(f"{t} failed on {folder}:\n{r['output'][-3000:]}")
                row["whole"][t].append({k: r[k] for k in ("wall", "cpu", "rss_mib")})
                print(f"{label} {t} run {i}: {r['wall']:.2f} s wall, {r['cpu']:.2f} s CPU, {r['rss_mib']:.0f} MiB",
                      file=sys.stderr)
        if args.outside:
            row["outside"] = {t: [] for t in trees}
            for i in range(args.runs):
                for t, tree in trees.items():
                    run_dir = args.work / "runs" / f"{folder.name}_{t}_outside"
                    shutil.rmtree(run_dir, ignore_errors=True)
                    r = _run_child([py, "-c", _OUTSIDE_HARNESS, "segment", str(folder), "--out", str(run_dir)], tree,
                                   _env(tree))
                    line = [x for x in r["output"].splitlines() if x.startswith("OUTSIDE=")]
                    if r["rc"] != 0 or not line:
                        raise SystemExit(f"{t} failed on {folder}:\n{r['output'][-3000:]}")
                    row["outside"][t].append(float(line[-1][8:]))
                    print(f"{label} {t} outside run {i}: {row['outside'][t][-1]:.3f} s CPU outside the core",
                          file=sys.stderr)
        if len(trees) == 2:
            row["same_outputs"] = _same_outputs(*(args.work / "runs" / f"{folder.name}_{t}" for t in trees))
        if not args.no_core:
            # one process per tree and run, alternating like the whole command (a process that
            # made all of one tree's calls in a row saw a different machine load than the other)
            row["core"] = {t: {"first": [], "warm": []} for t in trees}
            for i in range(args.runs):
                for t, tree in trees.items():
                    r = _run_child([py, "-c", _CORE_HARNESS, str(folder), "1"], tree, _env(tree))
                    line = [x for x in r["output"].splitlines() if x.startswith("CORE=")]
                    if r["rc"] != 0 or not line:
                        raise SystemExit(f"{t} core failed on {folder}:\n{r['output'][-3000:]}")
                    calls = json.loads(line[0][5:])
                    row["core"][t]["first"].append(calls[0])
                    row["core"][t]["warm"].extend(calls[1:])
                    print(f"{label} {t} core run {i}: first {calls[0][0]:.2f} s, warm {calls[1][0]:.2f} s wall",
                          file=sys.stderr)
        results.append(row)
    _print_table(results, list(trees))
    load = (load_start, os.getloadavg())
    print(f"\nload average (1, 5, 15 min) at the start {load[0][0]:.1f} {load[0][1]:.1f} {load[0][2]:.1f}, "
          f"at the end {load[1][0]:.1f} {load[1][1]:.1f} {load[1][2]:.1f}")
    if args.out:
        args.out.write_text(json.dumps({"trees": {t: str(p) for t, p in trees.items()}, "base_ref": args.base,
                                        "current_ref": args.current, "load_average": load,
                                        "runs": args.runs, "results": results}, indent=1))


def _print_table(results: list[dict], trees: list[str]) -> None:
    med = statistics.median
    has_base = "base" in trees
    head = "| scene | measure | " + (" base | current | current / base |" if has_base else " current |") + " target |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))

    def line(scene: str, what: str, vals: dict, fmt: str, target: float | None) -> None:
        cells = [fmt.format(vals[t]) for t in trees]
        if has_base:
            cells.append(f"{vals['current'] / vals['base']:.2f}" if vals["base"] else "–")
        tgt = "–" if target is None else f"<= {target:g}" + (" " + ("met" if vals["current"] <= target else "missed"))
        print(f"| {scene} | {what} | " + " | ".join(cells) + f" | {tgt} |")

    for row in results:
        t_whole, t_core, t_rss = TARGETS.get(row["kind"], (None, None, None))
        w = row["whole"]
        line(row["scene"], "whole command, wall s (median)", {t: med(x["wall"] for x in w[t]) for t in trees}, "{:.2f}",
             t_whole)
        line(row["scene"], "whole command, CPU s (median)", {t: med(x["cpu"] for x in w[t]) for t in trees}, "{:.2f}",
             t_whole)
        line(row["scene"], "whole command, peak RSS MiB (max)", {t: max(x["rss_mib"] for x in w[t]) for t in trees},
             "{:.0f}", t_rss)
        line(row["scene"], "whole command, peak RSS MiB (median)",
             {t: med(x["rss_mib"] for x in w[t]) for t in trees}, "{:.0f}", None)
        if has_base:
            # each current run against the base run just before it (the same moment's load): on a
            # shared machine the load drifts between runs more than the change moves the medians
            for what in ("wall", "cpu"):
                r = [c[what] / b[what] for b, c in zip(w["base"], w["current"])]
                print(f"| {row['scene']} | whole command, {what}: median of the paired current / base | | | "
                      f"{med(r):.2f} (runs {min(r):.2f}-{max(r):.2f}) | |")
        if row.get("outside"):
            o = row["outside"]
            line(row["scene"], "whole command, CPU s outside the core (median)", {t: med(o[t]) for t in trees},
                 "{:.3f}", None)
            if has_base:
                r = [c / b for b, c in zip(o["base"], o["current"])]
                print(f"| {row['scene']} | whole command, CPU outside the core: median of the paired current / base"
                      f" | | | {med(r):.2f} (runs {min(r):.2f}-{max(r):.2f}) | |")
        if row["core"]:
            c = row["core"]
            line(row["scene"], "core, first call wall s (median)", {t: med(x[0] for x in c[t]["first"]) for t in trees},
                 "{:.2f}", None)
            line(row["scene"], "core, warm wall s (median)", {t: med(x[0] for x in c[t]["warm"]) for t in trees},
                 "{:.2f}", t_core)
            line(row["scene"], "core, warm CPU s (median)", {t: med(x[1] for x in c[t]["warm"]) for t in trees},
                 "{:.2f}", t_core)
            # the calling thread's own CPU: the part of the core no second thread takes over;
            # on an idle 2-core machine the wall is about that plus half the normals' CPU (their
            # blocks run on two threads while the caller waits): session 6, checked against the
            # quiet base measurement (1.05 estimated, 1.06-1.09 s measured)
            line(row["scene"], "core, warm main-thread CPU s (median)",
                 {t: med(x[2] for x in c[t]["warm"]) for t in trees}, "{:.2f}", None)
            line(row["scene"], "core, warm wall on 2 idle cores, estimate s (main + normals / 2)",
                 {t: med(x[2] + x[3] / 2 for x in c[t]["warm"]) for t in trees}, "{:.2f}", t_core)
        if "same_outputs" in row:
            print(f"| {row['scene']} | instances, cloud, trace arrays identical to base | {row['same_outputs']} | | | |")


if __name__ == "__main__":
    main()
