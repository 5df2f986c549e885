"""Benchmark the correction log: undo / redo / apply latency and reopening time vs history length.

Usage:
    .venv/bin/python benchmarks/bench_annotations.py [--points 200000] [--history 100 1000 10000]
        [--old] [--out bench_annotations.json]

A synthetic run folder of ``--points`` points (super-voxels of ~100 points, 60 instances) gets
``H`` random edits through the public API (``Annotations.apply_op``: relabel / split / merge /
category / delete / box-like point ranges, each fsynced), then we time, at that history length:
apply (a new Relabel of 3 super-voxels), undo, redo (median and max of ``--reps`` each, every
call fsyncs one log line), ``save()`` (the checkpoint) and ``Annotations.open`` (reopening:
parse + checkpoint + tail replay), once with a checkpoint 0 entries behind and once with none.
``--old`` also times the code before issue 12 (``--old-rev``, git 93c922a) on the same log, in the same process
(its undo replays the whole history, so it runs only ``--old-reps`` undos).

Not a unit test: times depend on the disk (fsync) and the machine's load; printed, with the
machine's description.
"""

from __future__ import annotations

import argparse
import importlib.util
import io
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np

from clutt3r_core.annotations import Annotations, Delete, Merge, Relabel, SetCategory, Split
from clutt3r_core.errors import SceneError

REPO = Path(__file__).resolve().parents[1]


def make_run(folder: Path, n: int, seed: int = 0) -> tuple[np.ndarray, int]:
    rng = np.random.default_rng(seed)
    ks = max(n // 100, 10)
    sv = np.sort(rng.integers(0, ks, n)).astype(np.int32)
    sv[:ks] = np.arange(ks)
    sv.sort()
    k = 60
    sv_inst = rng.integers(-1, k, ks)
    sv_inst[:k] = np.arange(k)
    inst = sv_inst[sv].astype(np.int32)
    folder.mkdir(parents=True)
    for name, arrays in (("instances.npz", dict(points=np.zeros((n, 3), np.float32), instance=inst,
                                                 scores=np.linspace(0.9, 0.5, k).astype(np.float32))),
                         ("cloud.npz", dict(sv_labels=sv, sv_support=np.zeros(ks, bool)))):
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        (folder / name).write_bytes(buf.getvalue())
    return sv, ks


def random_edit(rng, a: Annotations, n: int, ks: int):
    lab = a.current
    alive = lab.alive
    r = rng.random()
    if r < 0.35:
        return Relabel(int(rng.choice(alive)), supervoxels=tuple(rng.integers(0, ks, 3).tolist()))
    if r < 0.55:
        s = int(rng.integers(0, n - 3000))
        return Relabel(int(rng.choice(alive)), points=tuple(range(s, s + int(rng.integers(200, 3000)))))
    if r < 0.75:
        return Split(supervoxels=tuple(rng.integers(0, ks, 4).tolist()))
    if r < 0.9:
        return SetCategory(int(rng.choice(alive)), f"cat{int(rng.integers(0, 20))}")
    if r < 0.95 and len(alive) > 2:
        i, j = rng.choice(alive, 2, replace=False)
        return Merge(int(i), int(j))
    return Delete(int(rng.choice(alive))) if len(alive) > 2 else SetCategory(int(alive[0]), "x")


def grow(a: Annotations, upto: int, rng, n: int, ks: int) -> None:
    while a.num_ops < upto:
        try:
            a.apply_op(random_edit(rng, a, n, ks))
        except SceneError:
            pass


def timed(f, reps: int) -> list[float]:
    out = []
    for _ in range(reps):
        t = time.perf_counter()
        f()
        out.append((time.perf_counter() - t) * 1e3)
    return out


def load_old(rev: str) -> types.ModuleType:
    """annotations.py at ``rev``, importable beside the current one (it only needs corrections'
    _apply_edit / _initial, which still exist)."""
    src = subprocess.run(["git", "show", f"{rev}:clutt3r_core/annotations.py"], cwd=REPO, check=True,
                         capture_output=True, text=True).stdout
    spec = importlib.util.spec_from_loader("old_annotations", loader=None)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["old_annotations"] = mod  # dataclasses look their module up there
    exec(compile(src, "old_annotations.py", "exec"), mod.__dict__)
    return mod


def measure(cls, run: Path, reps: int, n: int, ks: int, rng) -> dict:
    a = cls.open(run, author="bench")
    apply_ms = timed(lambda: a.apply_op(Relabel(int(a.current.alive[0]), supervoxels=(1, 2, 3))), reps)
    undo_ms = timed(a.undo, reps)
    redo_ms = timed(a.redo, reps)
    t = time.perf_counter()
    a.save()
    save_ms = (time.perf_counter() - t) * 1e3
    a.close()
    t = time.perf_counter()
    cls.open(run, readonly=True)
    reopen_snap = (time.perf_counter() - t) * 1e3
    snap = run / "corrections" / "instances_corrected.npz"
    hidden = snap.with_name("hidden.npz")
    snap.rename(hidden)
    t = time.perf_counter()
    cls.open(run, readonly=True)
    reopen_nosnap = (time.perf_counter() - t) * 1e3
    hidden.rename(snap)
    f = lambda v: {"median": float(np.median(v)), "max": float(np.max(v))}  # noqa: E731
    return {"apply_ms": f(apply_ms), "undo_ms": f(undo_ms), "redo_ms": f(redo_ms), "save_ms": save_ms,
            "reopen_checkpoint_ms": reopen_snap, "reopen_replay_ms": reopen_nosnap,
            "log_bytes": (run / "corrections" / "ops.jsonl").stat().st_size}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=200_000)
    ap.add_argument("--history", type=int, nargs="+", default=[100, 1000, 10_000])
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--old", action="store_true")
    ap.add_argument("--old-rev", default="93c922a")  # main before issue 12
    ap.add_argument("--old-reps", type=int, default=3)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, python {sys.version.split()[0]}")
    old = load_old(args.old_rev) if args.old else None
    rng = np.random.default_rng(1)
    results = []
    with tempfile.TemporaryDirectory() as d:
        run = Path(d) / "run"
        sv, ks = make_run(run, args.points)
        a = Annotations.open(run, author="bench")
        for h in sorted(args.history):
            t = time.perf_counter()
            grow(a, h, rng, args.points, ks)
            a.close()
            print(f"history {h}: built in {time.perf_counter() - t:.1f} s")
            row = {"history": h, "new": measure(Annotations, run, args.reps, args.points, ks, rng)}
            if old is not None:
                row["old"] = measure(old.Annotations, run, args.old_reps, args.points, ks, rng)
            results.append(row)
            print(json.dumps(row))
            a = Annotations.open(run, author="bench")
        a.close()
    print("\n| edits | code | apply ms (med/max) | undo ms | redo ms | save ms | reopen, checkpoint ms | reopen, replay ms |")
    print("|---|---|---|---|---|---|---|---|")
    for row in results:
        for code in ("old", "new"):
            if code in row:
                r = row[code]
                c = lambda k: f"{r[k]['median']:.1f} / {r[k]['max']:.1f}"  # noqa: E731
                print(f"| {row['history']} | {code} | {c('apply_ms')} | {c('undo_ms')} | {c('redo_ms')} | "
                      f"{r['save_ms']:.0f} | {r['reopen_checkpoint_ms']:.0f} | {r['reopen_replay_ms']:.0f} |")
    if args.out:
        args.out.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
