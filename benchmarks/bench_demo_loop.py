"""The demo loop after an update: query and grasp on the scene after an update vs the run as segmented.

    .venv/bin/python benchmarks/bench_demo_loop.py --root /tmp/h5/pairs --preset hard --seed 301

Makes (or reuses) a generated pre/post pair (``bench_update.make_pair``), runs ``clutt3r update RUN
--frame <post frame>`` once, then measures in one process, step 0 and the latest step alternating
(CPU time, ``time.process_time``: the machine is shared): ``scene_after``, ``RunQuery.open`` (the
first one embeds the masks), one query per phrase, one antipodal grasp per displaced / added
instance; and checks what the loop must get right: the removed instance is not ranked (its dominant
colour as the query), the displaced instance's grasp contacts lie on its moved points.
Results: docs/query.md, "After an update: the demo loop".
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_update import make_pair  # noqa: E402

from clutt3r_core.grasping.request import request_from_segmentation, run_views  # noqa: E402
from clutt3r_core.runs import run_voxel_size  # noqa: E402
from clutt3r_core.query import RunQuery, create_grounder  # noqa: E402
from clutt3r_core.registry import create_backend  # noqa: E402
from clutt3r_core.runs import load_run  # noqa: E402
from clutt3r_core.update.scene_after import scene_after  # noqa: E402

PHRASES = ("the red object", "the blue box", "a mug", "the green bottle", "yellow")


def _cpu(f, n: int):
    out, r = [], None
    for _ in range(n):
        c = time.process_time()
        r = f()
        out.append(time.process_time() - c)
    return r, float(np.median(out))


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", type=Path, default=Path("/tmp/demo_loop"))
    ap.add_argument("--preset", default="hard")
    ap.add_argument("--seed", type=int, default=301)
    a = ap.parse_args()
    scene_dir, run = make_pair(a.root, a.preset, a.seed)
    if not (run / "updates").is_dir():
        frame = json.loads((scene_dir / "gt" / "interaction.json").read_text())["post_frame"]
        subprocess.run([sys.executable, "-m", "clutt3r_core", "update", str(run), "--frame", str(frame)], check=True,
                       stdout=subprocess.DEVNULL)
    seg = load_run(run)
    sa, t1 = _cpu(lambda: scene_after(run, seg=seg), 5)
    sa0, t0 = _cpu(lambda: scene_after(run, 0, seg=seg), 5)
    print(f"scene_after: step {sa.step} {t1 * 1e3:.1f} ms CPU, step 0 {t0 * 1e3:.1f} ms; points {len(sa.points)} vs "
          f"{len(sa0.points)}; removed {dict(sa.removed)} displaced {sa.displaced} added {dict(sa.added)}")
    g = create_grounder()
    rq0, t = _cpu(lambda: RunQuery.open(run, grounder=g, step=0), 1)
    print(f"RunQuery.open step 0: {t:.2f} s CPU")
    rq1, t = _cpu(lambda: RunQuery.open(run, grounder=g), 1)
    print(f"RunQuery.open step {sa.step}: {t:.2f} s CPU (added described: {sorted(rq1.described)})")
    q0, q1 = [], []
    for _ in range(3):
        for q in PHRASES:
            q0.append(_cpu(lambda: rq0.query(q), 1)[1])
            q1.append(_cpu(lambda: rq1.query(q), 1)[1])
    print(f"query CPU median: step 0 {np.median(q0) * 1e3:.1f} ms, step {sa.step} {np.median(q1) * 1e3:.1f} ms "
          f"({len(q0)} each, alternating)")
    for k in sa.removed:
        dom = rq0.query("x").explanations[k].dominant_colors[0][0]
        r0, r1 = rq0.query(dom), rq1.query(dom)
        print(f"removed I{k} (dominant colour '{dom}'): step 0 -> I{r0.target}, step {r1.step} -> I{r1.target}; "
              f"I{k} ranked after the update: {k in r1.ranking}")
    gp = create_backend("grasp_planner", "antipodal")
    views, _ = run_views(run, None)
    vox = run_voxel_size(seg)  # as clutt3r grasp --step declares it
    for k in list(sa.displaced) + sorted(sa.added):
        req1 = sa.grasp_request(k, voxel_size=vox)
        p1 = []
        p0 = []
        for _ in range(3):
            if k < seg.num_instances:
                req0 = request_from_segmentation(seg, k, views)
                g0, t = _cpu(lambda: gp.plan(req0), 1)
                p0.append(t)
            g1, t = _cpu(lambda: gp.plan(req1), 1)
            p1.append(t)
        line = f"grasp I{k}: step {sa.step} {np.median(p1):.2f} s CPU, {len(g1)} grasps"
        if p0:
            line += f"; step 0 {np.median(p0):.2f} s CPU, {len(g0)} grasps"
            if len(g1) and g1.contacts is not None:
                cont = g1.contacts.reshape(-1, 3)
                new, old = sa.points_of(k)[0], seg.points[seg.instance == k]
                line += (f"; contacts to its moved points max {cKDTree(new).query(cont)[0].max() * 1e3:.1f} mm, "
                         f"to where it was min {cKDTree(old).query(cont)[0].min() * 1e3:.1f} mm")
        print(line)


if __name__ == "__main__":
    main()
