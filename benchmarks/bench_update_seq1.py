"""Time of ``update_scene`` on the real sample_seq1 frames 8 and 9 (RGB-only, chained; issue 10's
"< 3 s per update"), with a fingerprint of every result so a speed change can be shown exact.

Frame 8 updates the run's state; frame 9 updates the state after frame 8 (in memory, as
``clutt3r update RUN --frame 8`` then ``--frame 9`` chain on disk). Each frame runs ``--reps``
times in one process: the first call also pays the process's one-time costs (importing torch
for the pose optimiser, first calls into scipy / OpenCV), the later ones are the steady state.
CPU time (``time.process_time``, all threads) is the fair number on a shared machine; wall is
printed too (torch is imported in the calling thread when the first fit needs it: a background
import measured no wall gain on the 2-core machine, docs/update.md "Session 6: update time").

The fingerprint hashes, per instance, the status, the association's match, the IoUs and the
bytes of T_world: equal fingerprints = bit-identical results. To compare two versions of the
code, run this script with ``PYTHONPATH`` pointing at an export of the other one (``git archive
COMMIT | tar -x -C DIR``), alternating, on the same RUN.

Usage::

    clutt3r segment /work/shared/data/clutt3r-samples/sample_seq1 --out /tmp/run_seq1   # once
    .venv/bin/python benchmarks/bench_update_seq1.py /tmp/run_seq1 [--reps 2] [--profile /tmp/seq1.prof]

``--profile FILE``: cProfile (CPU clock) of the last call of each frame, saved as FILE.8 / FILE.9
and summarised (top functions by cumulative and by own time).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import time
from pathlib import Path

SAMPLE = Path("/work/shared/data/clutt3r-samples/sample_seq1")


def fingerprint(result) -> str:
    import numpy as np

    rec = [(int(r.instance), r.status, r.match, r.iou_before, r.iou_after,
            None if r.T_world is None else np.asarray(r.T_world, np.float64).tobytes().hex())
           for r in result.instances]
    return hashlib.sha1(json.dumps(rec).encode()).hexdigest()[:12]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="a run folder of sample_seq1 (clutt3r segment)")
    ap.add_argument("--scene", type=Path, default=SAMPLE)
    ap.add_argument("--reps", type=int, default=2)
    ap.add_argument("--profile", type=Path, default=None)
    a = ap.parse_args()
    if not a.scene.is_dir():
        raise SystemExit(f"{a.scene}: sample_seq1 not found (pass --scene)")
    c0 = time.process_time()
    from clutt3r_core.io import load_scene
    from clutt3r_core.update.state import apply_update, state_from_run
    from clutt3r_core.update.types import UpdateConfig
    from clutt3r_core.update.update import update_scene

    sc = load_scene(a.scene)
    cfg = UpdateConfig()
    state = state_from_run(a.run)
    print(f"imports and loading: {time.process_time() - c0:.2f} s CPU")
    for frame in (8, 9):
        view = sc.view_by_frame(frame)
        cpu, wall, fps = [], [], set()
        for rep in range(a.reps):
            prof = None
            if a.profile is not None and rep == a.reps - 1:
                import cProfile

                prof = cProfile.Profile(time.process_time)
                prof.enable()
            c, w = time.process_time(), time.perf_counter()
            res = update_scene(state, view, cfg)
            cpu.append(time.process_time() - c)  # every thread's (the optimiser's import runs on one)
            wall.append(time.perf_counter() - w)
            if prof is not None:
                prof.disable()
                out = Path(f"{a.profile}.{frame}")
                prof.dump_stats(out)
                import pstats

                st = pstats.Stats(str(out))
                st.sort_stats("cumulative").print_stats(25)
                st.sort_stats("tottime").print_stats(20)
            fps.add(fingerprint(res))
        statuses = {int(r.instance): r.status for r in res.instances}
        print(f"frame {frame}: CPU s per call {[round(x, 2) for x in cpu]}, wall {[round(x, 2) for x in wall]} "
              "(first call pays one-time costs); "
              f"fingerprint {'/'.join(sorted(fps))}; {statuses}")
        state = apply_update(state, res)


if __name__ == "__main__":
    main()
