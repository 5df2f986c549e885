"""Time the geometric stages (fuse_views, build_supervoxels, mask_occupancy) on the real samples.

Usage: .venv/bin/python benchmarks/bench_geometry.py [--runs 3] [--stride 0]
Prints the median wall time of each stage over ``--runs`` runs, the peak RSS of the
process (resource.getrusage, so it includes loading the scene) and the sizes:
voxels N, super-voxels K, fraction of single-voxel super-voxels, fraction of voxels
marked support. Not a unit test; the numbers depend on the machine.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import time
from pathlib import Path

import numpy as np

from clutt3r_core.io.sample_layout import load_sample_layout
from clutt3r_core.occupancy import mask_occupancy
from clutt3r_core.pointcloud import PointCloudConfig, fuse_views
from clutt3r_core.supervoxels import build_supervoxels

SAMPLES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "clutt3r-samples"


def _timed(fn, runs: int):
    times, out = [], None
    for _ in range(runs):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--stride", type=int, default=0, help="pixel stride, 0 = auto")
    args = ap.parse_args()
    import open3d  # noqa: F401  (import cost is not part of any stage)

    cfg = PointCloudConfig(pixel_stride=args.stride)
    rows = []
    for name in ("sample_seq1", "sample_seq4"):
        root = SAMPLES / name / "data"
        if not root.is_dir():
            print(f"skip {name}: {root} not found")
            continue
        views = load_sample_layout(root, load_gt=False).initial_views
        t_fuse, cloud = _timed(lambda: fuse_views(views, cfg), args.runs)
        t_sv, sv = _timed(lambda: build_supervoxels(cloud), args.runs)
        n_masks = sum(len(v.masks) for v in views)
        t_occ, _ = _timed(
            lambda: [mask_occupancy(cloud, sv, i, v.masks.masks) for i, v in enumerate(views)], args.runs
        )
        h, w = views[0].depth.shape
        rows.append(
            (name, f"{len(views)}x{w}x{h}", cloud.stride[0], t_fuse, t_sv, t_occ, n_masks, t_fuse + t_sv + t_occ,
             cloud.num, sv.num, float((sv.sizes == 1).mean()), float(sv.voxel_support().mean()))
        )
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    head = ("sample", "views", "stride", "fuse s", "supervox s", "occup s", "masks", "total s",
            "voxels", "supervox", "single", "support")
    print(" | ".join(head))
    for r in rows:
        print(" | ".join([r[0], r[1], str(r[2]), f"{r[3]:.3f}", f"{r[4]:.3f}", f"{r[5]:.3f}", str(r[6]),
                          f"{r[7]:.3f}", str(r[8]), str(r[9]), f"{r[10]:.1%}", f"{r[11]:.1%}"]))
    print(f"peak RSS of the process: {peak_mb:.0f} MB (median of {args.runs} runs per stage)")


if __name__ == "__main__":
    main()
