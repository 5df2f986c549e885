"""``clutt3r export-gt RUN OUT [--scene DIR]``: a corrected run as a benchmark scene folder.

The layout and how labels reach the pixels: ``clutt3r_core.export_gt``. ``clutt3r bench
--scenes-dir OUT`` then scores methods on it.
"""

from __future__ import annotations

import time
from pathlib import Path

from tyro.conf import Positional

__all__ = ["export_gt_command"]


def export_gt_command(
    run: Positional[Path],
    out: Positional[Path],
    scene: Path | None = None,
    max_gap_m: float = 0.01,
) -> None:
    """Export the run's corrected labels (corrections/ops.jsonl) as ground truth: gt/points.npz,
    gt/objects.json, gt/instance_FRAME.png per view, COCO RLE JSON per view, ScanNet-style per-point text.

    Args:
        run: the run folder (``clutt3r segment`` output, corrected in the viewer's Edit tab).
        out: a new scene folder (refused when it already holds ground truth).
        scene: the run's scene folder (default: the one recorded in run.json).
        max_gap_m: metres; a depth pixel farther than this from every run point stays background.
    """
    from clutt3r_core.export_gt import ExportConfig, export_ground_truth

    t = time.perf_counter()
    s = export_ground_truth(run, out, scene=scene, config=ExportConfig(max_gap_m=max_gap_m))
    print(f"{s.out}: {s.num_objects} objects, {s.labelled_points}/{s.num_points} points labelled, "
          f"{len(s.views)} views ({int(s.pixels_labelled.sum())} object pixels) in {time.perf_counter() - t:.1f} s")
    print(f"score methods on it: clutt3r bench --scenes-dir {s.out}")
