"""Fuzz the scene loaders for minutes: the property of tests/core/robustness/test_fuzz_loaders.py
(``load_scene`` on a corrupted scene returns a Scene or raises a ``Clutt3rError``, nothing
else), run in rounds of fresh random examples until the time is up.

Usage: .venv/bin/python benchmarks/fuzz_loaders.py [--minutes 3] [--kinds json png npz run] [--round 200]
(run: a run folder's run.json / trace.json / npz files, read by ``load_run``)
Prints the examples run per kind, how many loaded / were refused with a typed error,
and every other exception (the minimal failing example hypothesis shrank it to).
Exit status 1 when any bug was found. Not a unit test.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import traceback
from collections import Counter
from pathlib import Path

from hypothesis import HealthCheck, given, settings

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repo root: tests.* helpers

from tests.core.robustness._fuzz import (  # noqa: E402
    apply,
    check_loads,
    check_run_loads,
    corruptions,
    run_corruptions,
)


def _round(kind: str, n: int, tmp: Path, outcomes: Counter):
    """One hypothesis run of ``n`` fresh examples of ``kind`` (database=None: nothing replayed)."""

    @settings(max_examples=n, deadline=None, database=None, suppress_health_check=list(HealthCheck))
    @given(run_corruptions() if kind == "run" else corruptions(kinds=(kind,)))
    def prop(c):
        check = check_run_loads if kind == "run" else check_loads
        outcomes[(kind, check(apply(c, tmp)))] += 1

    return prop


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=3.0)
    ap.add_argument("--kinds", nargs="+", default=["json", "png", "npz", "run"], choices=["json", "png", "npz", "run"])
    ap.add_argument("--round", type=int, default=200, help="examples per hypothesis round")
    args = ap.parse_args()

    outcomes: Counter = Counter()
    bugs: list[str] = []
    deadline = time.monotonic() + 60 * args.minutes
    rounds = 0
    with tempfile.TemporaryDirectory() as tmp:
        while time.monotonic() < deadline:
            for kind in args.kinds:
                try:
                    _round(kind, args.round, Path(tmp), outcomes)()
                except Exception as e:  # hypothesis re-raises the shrunk failing example
                    bugs.append(f"[{kind}] {type(e).__name__}: {e}\n{traceback.format_exc(limit=-6)}")
                    outcomes[(kind, "BUG")] += 1
                if time.monotonic() >= deadline:
                    break
            rounds += 1

    total = sum(outcomes.values())
    print(f"{total} examples in {args.minutes:g} min ({rounds} rounds):")
    for kind in args.kinds:
        ok, err, bug = (outcomes[(kind, k)] for k in ("ok", "error", "BUG"))
        print(f"  {kind:4s}: {ok + err + bug:6d} examples, {ok} loaded, {err} refused with a Clutt3rError, {bug} bugs")
    for b in bugs:
        print("\nBUG " + b)
    sys.exit(1 if bugs else 0)


if __name__ == "__main__":
    main()
