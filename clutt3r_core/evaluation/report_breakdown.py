"""Report sections of issue 13: where strict-IoU AP is lost (``evaluation.breakdown``) and the
depth-model sweep. Kept apart from ``report.py`` (which calls ``breakdown_section`` and
``depth_section``) so that the two grow independently; both return Markdown lines."""

from __future__ import annotations

import math
from collections import defaultdict

import numpy as np

from clutt3r_core.evaluation.breakdown import ERROR_KINDS, SENSOR_KINDS

__all__ = ["breakdown_section", "depth_section"]

_DIFF = ("easy", "intermediate", "hard")


def _f(x: float, nd: int = 1) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    return "\n".join(lines + ["| " + " | ".join(r) + " |" for r in rows])


def _row(label: str, bs: list) -> list[str]:
    """One table row: means over the breakdowns ``bs`` (one scene: its own numbers)."""
    m = lambda f: float(np.mean([f(b) for b in bs]))  # noqa: E731
    row = [label, _f(m(lambda b: b.num_gt), 0 if len(bs) == 1 else 1), _f(m(lambda b: b.num_pred), 0 if len(bs) == 1 else 1),
           _f(m(lambda b: b.num_fragments), 0 if len(bs) == 1 else 1),
           " / ".join(_f(m(f), 0 if len(bs) == 1 else 1) for f in (lambda b: b.num_spurious, lambda b: b.num_merged_objects,
                                                                   lambda b: b.num_missed_objects)),
           _f(m(lambda b: b.ap)), _f(m(lambda b: b.ap_all_fixed))]
    row += [f"{_f(m(lambda b, k=k: b.gain(k)))} ({_f(100 * m(lambda b, k=k: b.cell_fraction(k)), 0)}%)" for k in ERROR_KINDS]
    return row


def breakdown_section(res_main, method: str = "ours") -> list[str]:
    """Per-scene breakdown of ``method``'s results (those with a breakdown), with a mean row per difficulty."""
    rr = [r for r in res_main if r.method == method and r.breakdown is not None]
    if not rr:
        return []
    by_d = defaultdict(list)
    for r in rr:
        by_d[r.difficulty].append(r)
    rows = []
    for d in [x for x in _DIFF if x in by_d] + sorted(set(by_d) - set(_DIFF)):
        for r in sorted(by_d[d], key=lambda r: r.scene):
            rows.append(_row(r.scene, [r.breakdown]))
        if len(by_d[d]) > 1:
            rows.append(_row(f"**{d} (mean)**", [r.breakdown for r in by_d[d]]))
    header = ["scene", "GT", "pred", "fragments", "spurious / merged / missed", "AP", "labelling ceiling"]
    header += [f"{k}{' (sensor)' if k in SENSOR_KINDS else ''}" for k in ERROR_KINDS]
    return [
        f"## Where strict-IoU AP is lost ({method})", "",
        "Every wrong 10 mm cell of a scene gets one cause (`clutt3r_core/evaluation/breakdown.py`); each "
        "cause's column is the AP (0.50:0.95) points an oracle that fixes only that cause gives back, and "
        "in parentheses its wrong cells as a share of the GT object cells. `hole` (GT surface with no fused "
        "point) and `off_gt` (fused points where the GT surface has none: the noisy surface spilling into "
        "neighbouring cells) are the sensor's and the fusion's: no labelling fixes them. `labelling ceiling` "
        "is the AP of a perfect labelling of the fused cloud (every other cause fixed). `fragments` = predicted "
        "instances that are a piece of an object another prediction covers; then predictions mostly off the "
        "objects, objects swallowed by a neighbour's prediction, objects with no prediction.", "",
        _table(header, rows), "",
    ]


def depth_section(depth_res, res_main, main_depth: str) -> list[str]:
    """AP of the methods on the sweep subset with each depth model (the main one from ``res_main``)."""
    if not depth_res:
        return []
    scenes = {r.scene for r in depth_res}
    both = [r for r in res_main if r.scene in scenes and r.method in {x.method for x in depth_res}] + list(depth_res)
    acc = defaultdict(list)
    for r in both:
        acc[(r.method, r.depth_noise)].append(r)
    depths = [main_depth] + sorted({r.depth_noise for r in depth_res} - {main_depth})
    rows = []
    for m in sorted({r.method for r in depth_res}):
        row = [m]
        for dn in depths:
            v = acc.get((m, dn), [])
            row += [_f(float(np.mean([getattr(r, a) for r in v]))) if v else "–" for a in ("ap25", "ap50", "ap")]
        rows.append(row)
    return [
        "## Depth-model sweep", "",
        f"The sweep subset ({len(scenes)} scenes) with each depth model of the generator (`clutt3r_core/synth/sensor.py`: "
        "`realsense` = disparity noise growing with z^2, holes at depth edges and grazing angles, 1 mm steps; "
        "`none` = clean rendered depth); the ground truth is the clean surface in both.", "",
        _table(["Method"] + [f"{dn} {a}" for dn in depths for a in ("AP25", "AP50", "AP")], rows), "",
    ]
