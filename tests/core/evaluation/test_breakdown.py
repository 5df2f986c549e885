"""Error breakdown on hand-made 10 mm grids: every kind of wrong cell, and the oracle gains."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation.breakdown import ERROR_KINDS, ErrorBreakdown, error_breakdown
from clutt3r_core.evaluation.metrics import evaluate_instances
from tests.core.evaluation.test_metrics import cells, make_gt, pred

# two objects of 10 x 4 x 4 cells, 2 cells apart, on a table slab under them
A, B = cells(0, 10, 0, 4, 1, 5), cells(12, 22, 0, 4, 1, 5)
TABLE = cells(0, 22, 0, 8, 0, 1)  # reaches 4 cells beyond the objects in y
GT = make_gt([(A, 0), (B, 1), (TABLE, -1)])
SC = np.array([0.9, 0.8, 0.7, 0.6])


def kinds(b: ErrorBreakdown) -> dict[str, int]:
    return {k: n for k, n in zip(ERROR_KINDS, b.wrong_cells) if n}


def test_perfect_prediction_has_no_wrong_cell():
    pts, lab = pred([(A, 0), (B, 1), (TABLE, -1)])
    b = error_breakdown(pts, lab, SC[:2], GT)
    assert kinds(b) == {} and b.ap == 100.0 and b.ap_all_fixed == 100.0
    assert (b.num_gt, b.num_pred, b.num_fragments, b.num_spurious) == (2, 2, 0, 0)
    assert b.gt_cells == len(A) + len(B)


def test_fragment_is_found_and_its_oracle_gives_ap_back():
    a_main, a_frag = A[A[:, 0] < 0.07], A[A[:, 0] >= 0.07]  # 7 + 3 columns of A
    pts, lab = pred([(a_main, 0), (a_frag, 2), (B, 1), (TABLE, -1)])
    b = error_breakdown(pts, lab, SC[:3], GT)
    assert b.num_fragments == 1 and b.num_pred == 3
    k = kinds(b)
    assert set(k) <= {"fragment", "boundary"} and k["fragment"] > 0
    assert k.get("fragment", 0) + k.get("boundary", 0) == len(a_frag)  # the cut face next to B is a boundary
    assert b.gain("fragment") > 0
    assert b.ap_all_fixed == 100.0


def test_merged_neighbours():
    pts, lab = pred([(A, 0), (B, 0), (TABLE, -1)])
    b = error_breakdown(pts, lab, SC[:1], GT)
    assert b.num_merged_objects == 1 and b.num_pred == 1
    assert kinds(b).keys() <= {"merged", "boundary"} and kinds(b)["merged"] > 0
    assert b.gain("merged") > 40  # recall 1/2 -> 1 at every threshold
    assert b.ap_all_fixed == 100.0


def test_missing_part_table_bleed_hole_and_off_gt():
    top = A[:, 2] > 0.04  # A's top layer unlabelled: a missing part
    off = cells(0, 10, 0, 4, 5, 7)  # two layers above A where the GT has no point
    far = TABLE[:, 1] > 0.06  # a table strip two cells away from both objects
    pts, lab = pred([(A[~top], 0), (A[top], -1), (off, 0), (B[B[:, 0] < 0.2], 1), (TABLE[far], 1), (TABLE[~far], -1)])
    b = error_breakdown(pts, lab, SC[:2], GT)
    k = kinds(b)
    assert k["hole"] == int(np.sum(B[:, 0] >= 0.2))  # no predicted point there at all
    assert k["off_gt"] == len(off) and k["missing"] > 0 and k["table"] == int(far.sum())
    ap, _ = evaluate_instances(pts, lab, SC[:2], GT)
    assert b.ap == pytest.approx(ap.ap)


def test_spurious_prediction_on_the_table():
    pts, lab = pred([(A, 0), (B, 1), (TABLE, 2)])
    b = error_breakdown(pts, lab, SC[:3], GT)
    assert b.num_spurious == 1 and b.num_fragments == 0


def test_no_prediction_at_all():
    pts, lab = pred([(A, -1), (B, -1), (TABLE, -1)])
    b = error_breakdown(pts, lab, np.zeros(0), GT)
    assert b.num_pred == 0 and b.ap == 0.0 and b.num_missed_objects == 2
    assert kinds(b) == {"missing": b.gt_cells - kinds(b).get("boundary", 0), **({"boundary": kinds(b)["boundary"]} if "boundary" in kinds(b) else {})}
    assert b.ap_all_fixed == 100.0


def test_json_round_trip_and_bad_input():
    pts, lab = pred([(A, 0), (B, 0), (TABLE, -1)])
    b = error_breakdown(pts, lab, SC[:1], GT)
    assert ErrorBreakdown.from_json(b.to_json()) == b
    with pytest.raises(SceneError):
        error_breakdown(pts, lab + 3, SC[:1], GT)
    with pytest.raises(SceneError):
        ErrorBreakdown(1, 1, 0, 0, 0, 0, 1, (0,), 0.0, (0.0,), 0.0)


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(-1, 3), min_size=len(A) + len(B), max_size=len(A) + len(B)))
def test_every_wrong_cell_has_one_kind_and_ap_matches_the_metric(labels):
    # random labels on the objects' own cells (no hole, no off-GT cell): the kinds partition the wrong cells
    pts = np.concatenate([A, B])
    lab = np.array(labels, np.int32)
    b = error_breakdown(pts, lab, SC, GT)
    ap, _ = evaluate_instances(pts, lab, SC, GT)
    assert b.ap == pytest.approx(ap.ap)
    assert b.wrong_cells[ERROR_KINDS.index("hole")] == 0 and b.wrong_cells[ERROR_KINDS.index("off_gt")] == 0
    assert sum(b.wrong_cells) <= len(pts)
    assert b.ap_all_fixed == pytest.approx(100.0)
    assert b.num_fragments + b.num_spurious <= b.num_pred
