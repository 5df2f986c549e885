"""Wall time of the same small ``clutt3r bench`` on each executor (issue 13, section 4).

Usage:
    .venv/bin/python benchmarks/bench_executors.py [--executors serial process dask]
        [--per-difficulty 1] [--size 320x240] [--methods ours naive maskclustering] [--repeats 1]

Each run is the whole command as a fresh process (``clutt3r bench --executor E``) with a cold,
private cache, on a snapshot of the package taken at the start, so the time includes imports,
scene generation, the jobs, the report and, for ``dask``, starting and stopping a local cluster of ``--workers`` processes (``process`` uses as
many). Then it checks that every executor gave the same results (AP, matches; not the times),
and that a second ``dask`` run is all cache. Prints one Markdown table. The numbers are only
meaningful on an otherwise idle machine; say what else ran.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "clutt3r_core"]
# measurements of the run, and provenance: everything else in a result must match
_RUN = {"stages", "wall_seconds", "peak_traced_mb", "maxrss_mb", "code_version", "cached"}


def _bench(executor: str, work: Path, args: argparse.Namespace, cache: Path, snap: Path) -> tuple[float, str]:
    w, h = args.size.split("x")
    cmd = CLI + ["bench", "--executor", executor, "--workers", str(args.workers), "--out", str(work / "out"),
                 "--cache", str(cache), "--per-difficulty", str(args.per_difficulty), "--width", w, "--height", h,
                 "--methods", *args.methods, "--no-view-sweep", "--no-noise-sweep", "--no-progress"]
    t0 = time.perf_counter()
    env = {**os.environ, "PYTHONPATH": str(snap)}
    out = subprocess.run(cmd, check=True, cwd=snap, env=env, stdout=subprocess.PIPE, text=True).stdout
    # the command's last line: "N jobs (M cached) in S s -> report"
    return time.perf_counter() - t0, out.strip().splitlines()[-1].split(" in ")[0]


def _results(work: Path) -> tuple[list[dict], float]:
    """The results less their run measurements, and the jobs' summed wall seconds (compute)."""
    rows = json.loads((work / "out" / "results.json").read_text())["results"]
    out = sorted(({k: v for k, v in r.items() if k not in _RUN} for r in rows), key=lambda r: r["key"])
    return out, sum(r["wall_seconds"] for r in rows)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--executors", nargs="+", default=["serial", "process", "dask"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--per-difficulty", type=int, default=1)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--methods", nargs="+", default=["ours", "naive", "maskclustering"])
    ap.add_argument("--repeats", type=int, default=1)
    args = ap.parse_args()

    rows, results, load = [], {}, os.getloadavg()[0]
    with tempfile.TemporaryDirectory(prefix="bench-executors-") as tmp:
        # a snapshot of the package: every run (and every worker) imports the same code even if
        # the tree is edited meanwhile, so the keys and the results are comparable
        snap = Path(tmp) / "snapshot"
        shutil.copytree(ROOT / "clutt3r_core", snap / "clutt3r_core", ignore=shutil.ignore_patterns("__pycache__"))
        for ex in args.executors:
            times, warm, said, busy = [], None, "", []
            for i in range(args.repeats):
                work = Path(tmp) / f"{ex}-{i}"
                t, said = _bench(ex, work, args, work / "cache", snap)
                times.append(t)
                results[ex], b = _results(work)
                busy.append(b)
                if ex == "dask" and warm is None:
                    warm = _bench(ex, work, args, work / "cache", snap)  # same cache: nothing to compute
                shutil.rmtree(work)
            rows.append((ex, times, said, busy))
            if warm is not None:
                rows.append(("dask, second run", [warm[0]], warm[1], []))
    ref = next(iter(results.values()))
    same = {ex: r == ref for ex, r in results.items()}
    n = len(ref)
    print(f"{n} jobs ({args.per_difficulty} scene(s) per difficulty at {args.size}, methods {' '.join(args.methods)}), "
          f"{args.workers} workers, {os.cpu_count()} CPUs, 1-min load average at the start: {load:.1f}\n")
    print("| executor | wall time (s), whole command | jobs' own wall time, summed (s) | the command said | results equal to the first |")
    print("|---|---|---|---|---|")
    for name, ts, said, busy in rows:
        ex = name.split(",")[0]
        fmt = lambda xs: " / ".join(f"{t:.1f}" for t in xs)  # noqa: E731
        print(f"| {name} | {fmt(ts)} | {fmt(busy) or '-'} | {said} | {same.get(ex, '') if busy else ''} |")
    if not all(same.values()):
        sys.exit("executors disagree")


if __name__ == "__main__":
    main()
