"""Record the pose fits' inputs and replay them through two versions of the pose optimiser in ONE
process (A/B): CPU ratio and how far the poses differ. This is how a speed change of
``clutt3r_core/update/pose.py`` / ``project.py`` is shown to keep the results (docs/update.md,
session 5).

- ``record-seq1 RUN OUT.pkl``: the ``PoseProblem`` of every silhouette fit of sample_seq1's frames
  8 and 9 (chained, as ``bench_update_seq1.py``), pickled.
- ``record-bench OUT.pkl -- <bench_update.py args>``: the same for ``benchmarks/bench_update.py``'s
  generated pairs (e.g. ``--out /tmp/bu --pairs 12 --seed0 300 --no-depth --embedder run``), with
  the ``bench_update.py`` of the checkout whose ``clutt3r_core`` is imported (``PYTHONPATH=DIR``
  records what DIR's code gives to the fits).
- ``ab --base DIR P.pkl [P.pkl ...]``: each problem through DIR's ``pose.py`` and ``project.py``
  (another checkout, e.g. ``git worktree add DIR COMMIT``; loaded under other module names) and
  through this checkout's, alternating the order per problem; prints the CPU of each, their
  ratio, and the rotation / centroid differences of the poses, the stages and the IoU after.

- ``gt --pairs DIR [--pairs DIR ...] --results NAME P.pkl [P.pkl ...] [--cfg LABEL=JSON ...] [--plane nx,ny,nz,d] [--oracle-rotation]``:
  the recorded problems of ``bench_update.py``'s generated pairs (``DIR`` its ``--out``, ``NAME``
  its results file there, e.g. ``results_hB.json``) re-fitted with each ``PoseConfig`` (JSON
  fields; stage fields as ``{"coarse": {"lambda_reg_z": 0}}``), for the displaced object's main
  instance of every pair where it was found, against the generator's true motion: rotation
  (raw) and centroid errors, median / p90, for upright (true tilt < 5 deg) and tipped objects
  (docs/update.md, session 5). ``--plane`` sets ``PoseProblem.support_plane`` where this
  checkout has it; ``--oracle-rotation`` starts every fit from the true rotation about the
  centroid (centroid on the mask's ray at its old height): what the translation would be if the
  tilt were known.

Run from the repository root: ``.venv/bin/python benchmarks/bench_pose_fits.py ...``. Pickles hold
numpy arrays and the project's dataclasses; read only your own.
"""

from __future__ import annotations

import argparse
import importlib.util
import pickle
import runpy
import sys
import time
from pathlib import Path

import numpy as np

SAMPLE = Path("/work/shared/data/clutt3r-samples/sample_seq1")


def _recording(probs: list):
    import clutt3r_core.update.update as U

    orig = U._LazyOptimizer.optimize

    def rec(self, problem):
        probs.append(problem)
        return orig(self, problem)

    U._LazyOptimizer.optimize = rec


def record_seq1(run: Path, out: Path, scene: Path = SAMPLE) -> None:
    from clutt3r_core.io import load_scene
    from clutt3r_core.update.state import apply_update, state_from_run
    from clutt3r_core.update.types import UpdateConfig
    from clutt3r_core.update.update import update_scene

    probs: list = []
    _recording(probs)
    sc = load_scene(scene)
    state = state_from_run(run)
    for f in (8, 9):
        state = apply_update(state, update_scene(state, sc.view_by_frame(f), UpdateConfig()))
    out.write_bytes(pickle.dumps(probs))
    print(f"{len(probs)} problems -> {out}")


def record_bench(out: Path, args: list[str]) -> None:
    import clutt3r_core

    probs: list = []
    _recording(probs)
    # the bench_update.py of the checkout whose code is imported (PYTHONPATH), so that they match
    bench = Path(clutt3r_core.__file__).resolve().parents[1] / "benchmarks" / "bench_update.py"
    sys.argv = [str(bench), *args]
    try:
        runpy.run_path(str(bench), run_name="__main__")
    finally:
        out.write_bytes(pickle.dumps(probs))
        print(f"{len(probs)} problems -> {out}")


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod  # dataclasses look their module up while the class is made
    spec.loader.exec_module(mod)
    return mod


def _err(T: np.ndarray, Tg: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """(rotation error deg, centroid error cm) of the motion T against Tg (the true motion, or another fit's)."""
    a = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3] @ Tg[:3, :3].T) - 1) / 2, -1, 1)))
    return float(a), float(np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - Tg[:3, :3] @ c - Tg[:3, 3])) * 100


def ab(base: Path, pickles: list[Path]) -> None:
    from clutt3r_core.update import pose as new
    from clutt3r_core.update.types import PoseConfig

    old = _load("bench_pose_base", base / "clutt3r_core/update/pose.py")
    old.splat = _load("bench_project_base", base / "clutt3r_core/update/project.py").splat  # its own splats
    cfg = PoseConfig()
    opts = {"base": old.TorchPoseOptimizer(cfg), "this": new.TorchPoseOptimizer(cfg)}
    cpu = {"base": 0.0, "this": 0.0}
    rows = []
    i = 0
    for path in pickles:
        for pb in pickle.loads(path.read_bytes()):
            res = {}
            for name in (("base", "this") if i % 2 == 0 else ("this", "base")):
                c = time.process_time()
                res[name] = opts[name].optimize(pb)
                cpu[name] += time.process_time() - c
            i += 1
            Ta, Tb = res["base"].T_world, res["this"].T_world
            dR, dt = _err(Ta, Tb, pb.points.astype(np.float64).mean(axis=0))
            rows.append((path.name, pb.instance, dR, dt, res["base"].iou_after, res["this"].iou_after,
                         res["base"].stages, res["this"].stages, bool(np.array_equal(Ta, Tb))))
    if not rows:
        raise SystemExit("no problems in the pickles")
    dR = np.array([r[2] for r in rows])
    dt = np.array([r[3] for r in rows])
    print(f"{len(rows)} fits: CPU base {cpu['base']:.2f} s, this {cpu['this']:.2f} s, ratio {cpu['this'] / cpu['base']:.3f}")
    print(f"rotation difference median {np.median(dR):.4f} / p90 {np.percentile(dR, 90):.3f} / max {dR.max():.3f} deg; "
          f"centroid median {np.median(dt):.4f} / p90 {np.percentile(dt, 90):.3f} / max {dt.max():.3f} cm; "
          f"bit-identical {sum(r[8] for r in rows)}; same stages {sum(r[6] == r[7] for r in rows)}; "
          f"same side of IoU 0.5 {sum((r[4] >= 0.5) == (r[5] >= 0.5) for r in rows)}")
    for r in rows:
        if r[2] > 0.5 or r[3] > 0.2 or r[6] != r[7] or (r[4] >= 0.5) != (r[5] >= 0.5):
            print(f"  {r[0]} instance {r[1]}: {r[2]:.2f} deg, {r[3]:.2f} cm, IoU after {r[4]:.3f} / {r[5]:.3f}, "
                  f"stages {r[6]} / {r[7]}")


def gt(pairs_dirs: list[Path], results: str, pickles: list[Path], cfgs: list[str], plane: str | None, oracle: bool) -> None:
    import json
    from dataclasses import fields, replace

    from clutt3r_core.io.images import read_rgb
    from clutt3r_core.update.pose import TorchPoseOptimizer, initial_translation, motion_matrix
    from clutt3r_core.update.types import PoseConfig

    def config(js: dict) -> PoseConfig:
        base = PoseConfig()
        kw = {k: (replace(getattr(base, k), **v) if isinstance(v, dict) else tuple(v) if isinstance(v, list) else v)
              for k, v in js.items()}
        return replace(base, **kw)

    named = dict(c.split("=", 1) for c in cfgs) if cfgs else {"default": "{}"}
    opts = {k: TorchPoseOptimizer(config(json.loads(v))) for k, v in named.items()}
    probs = [pb for path in pickles for pb in pickle.loads(path.read_bytes())]
    pl = None if plane is None else np.array([float(x) for x in plane.split(",")])
    cpu = dict.fromkeys(opts, 0.0)
    rows = []
    todo = [(d, p) for d in pairs_dirs for p in json.loads((d / results).read_text())["pairs"]]
    for pairs, p in todo:
        if not p.get("displaced_found"):
            continue
        sc = pairs / p["scene"] / "scene"
        inter = json.loads((sc / "gt/interaction.json").read_text())
        Tg = np.array(inter["T_new_old"])
        frames = json.loads((sc / "transforms.json").read_text())["frames"]
        fr = [f for f in frames if f"{inter['post_frame']:06d}" in f["file_path"]]
        ids = [int(k) for k, v in p["statuses"].items() if v[0] == "displaced" and v[1] == inter["displaced_object"]]
        rgb = read_rgb(sc / fr[0]["file_path"]) if fr else None
        cand = [pb for pb in probs if rgb is not None and pb.instance in ids and np.array_equal(pb.rgb, rgb)]
        if not cand:
            print(f"  {p['scene']}: no recorded problem of instances {ids}")
            continue
        pb = cand[0]
        if pl is not None and any(f.name == "support_plane" for f in fields(pb)):
            pb = replace(pb, support_plane=pl)
        c = pb.points.astype(np.float64).mean(axis=0)
        if oracle:
            pb = replace(pb, T_init=motion_matrix(Tg[:3, :3], c, initial_translation(pb, c)))
        row = [p["scene"], float(np.degrees(np.arccos(np.clip(Tg[2, 2], -1, 1))))]
        for k, o in opts.items():
            t0 = time.process_time()
            T = o.optimize(pb).T_world
            cpu[k] += time.process_time() - t0
            row += [*_err(T, Tg, c), float((T[:3, :3] @ c + T[:3, 3] - c)[2]) * 100]
        rows.append(row)
        print(f"  {row[0]} tilt {row[1]:.1f}: " + "  ".join(
            f"{k} {row[2 + 3 * j]:.1f} deg {row[3 + 3 * j]:.2f} cm" for j, k in enumerate(opts)), flush=True)
    if not rows:
        raise SystemExit("no pair with a recorded problem")
    a = np.array([r[1:] for r in rows], float)
    for name, m in (("upright (< 5 deg)", a[:, 0] < 5), ("tipped (>= 5 deg)", a[:, 0] >= 5)):
        if not m.any():
            continue
        print(f"{name}: {int(m.sum())} objects")
        for j, k in enumerate(opts):
            r, t, dz = a[m, 1 + 3 * j], a[m, 2 + 3 * j], a[m, 3 + 3 * j]
            print(f"  {k:16s} rotation median {np.median(r):6.1f} p90 {np.percentile(r, 90):6.1f} deg, "
                  f"translation median {np.median(t):5.2f} p90 {np.percentile(t, 90):5.2f} cm, "
                  f"fit centroid dz median {np.median(dz):+.2f} cm")
    print("CPU s: " + ", ".join(f"{k} {v:.1f}" for k, v in cpu.items()))


def main() -> None:
    argv = sys.argv[1:]
    rest: list[str] = []
    if "--" in argv:
        rest = argv[argv.index("--") + 1:]
        argv = argv[: argv.index("--")]
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    s1 = sub.add_parser("record-seq1")
    s1.add_argument("run", type=Path)
    s1.add_argument("out", type=Path)
    s1.add_argument("--scene", type=Path, default=SAMPLE)
    s2 = sub.add_parser("record-bench")
    s2.add_argument("out", type=Path)
    s3 = sub.add_parser("ab")
    s3.add_argument("--base", type=Path, required=True)
    s3.add_argument("pickles", type=Path, nargs="+")
    s4 = sub.add_parser("gt")
    s4.add_argument("--pairs", type=Path, action="append", required=True)
    s4.add_argument("--results", required=True)
    s4.add_argument("--cfg", action="append", default=[])
    s4.add_argument("--plane")
    s4.add_argument("--oracle-rotation", action="store_true")
    s4.add_argument("pickles", type=Path, nargs="+")
    a = ap.parse_args(argv)
    if a.cmd == "record-seq1":
        record_seq1(a.run, a.out, a.scene)
    elif a.cmd == "record-bench":
        record_bench(a.out, rest)
    elif a.cmd == "gt":
        gt(a.pairs, a.results, a.pickles, a.cfg, a.plane, a.oracle_rotation)
    else:
        ab(a.base, a.pickles)


if __name__ == "__main__":
    main()
