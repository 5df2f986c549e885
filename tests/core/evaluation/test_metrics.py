"""Metrics on hand-made cases: boxes of points on the 10 mm grid with known IoUs."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation.metrics import (
    AP_THRESHOLDS,
    MemoryProbe,
    average_precision,
    evaluate_instances,
    pooled_ap,
    semantic_iou,
    stage_times,
    voxelize_labels,
)
from clutt3r_core.scene import GroundTruth, ObjectInfo

V = 0.01


def cells(x0: int, x1: int, y0: int = 0, y1: int = 1, z0: int = 0, z1: int = 1) -> np.ndarray:
    """Points at the centres of the 10 mm cells [x0, x1) x [y0, y1) x [z0, z1)."""
    g = np.mgrid[x0:x1, y0:y1, z0:z1].reshape(3, -1).T
    return (g + 0.5) * V


def make_gt(parts: list[tuple[np.ndarray, int]], categories: list[str] | None = None) -> GroundTruth:
    pts = np.concatenate([p for p, _ in parts]).astype(np.float32)
    lab = np.concatenate([np.full(len(p), k, np.int32) for p, k in parts])
    k = int(lab.max()) + 1
    cats = categories or [f"c{i}" for i in range(k)]
    return GroundTruth(tuple(ObjectInfo(i, cats[i]) for i in range(k)), points=pts, point_labels=lab)


def pred(parts: list[tuple[np.ndarray, int]]) -> tuple[np.ndarray, np.ndarray]:
    pts = np.concatenate([p for p, _ in parts])
    lab = np.concatenate([np.full(len(p), k, np.int32) for p, k in parts])
    return pts, lab


# two 10-cell objects and 10 cells of table (background)
A, B, TABLE = cells(0, 10), cells(20, 30), cells(40, 50)
GT2 = make_gt([(A, 0), (B, 1), (TABLE, -1)])


def test_voxelize_majority_and_ties():
    p = np.array([[0.001, 0, 0], [0.002, 0, 0], [0.003, 0, 0], [0.015, 0, 0], [0.016, 0, 0]])
    v = voxelize_labels(p, np.array([2, 2, 5, 7, 3]))
    assert v.cells.tolist() == [[0, 0, 0], [1, 0, 0]]
    assert v.labels.tolist() == [2, 3]  # majority 2; tie 7 vs 3 -> lower label
    v = voxelize_labels(p[:3], np.array([-1, -1, 4]))
    assert v.labels.tolist() == [-1]  # background wins the vote like any label
    with pytest.raises(SceneError):
        voxelize_labels(p, np.zeros(3))


def test_perfect_prediction_is_100():
    pts, lab = pred([(A, 0), (B, 1), (TABLE, -1)])
    r, _ = evaluate_instances(pts, lab, np.array([0.9, 0.8]), GT2)
    assert (r.ap25, r.ap50, r.ap) == (100.0, 100.0, 100.0)
    assert r.num_gt == 2 and r.num_pred == 2


def test_empty_prediction_is_0():
    r, _ = evaluate_instances(np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros(0), GT2)
    assert (r.ap25, r.ap50, r.ap) == (0.0, 0.0, 0.0)
    pts, _ = pred([(A, 0), (B, 1)])
    r, _ = evaluate_instances(pts, np.full(len(pts), -1), np.zeros(0), GT2)  # all unassigned
    assert r.ap25 == 0.0 and r.num_pred == 0


def test_no_gt_is_nan():
    gt = GroundTruth((), points=TABLE.astype(np.float32), point_labels=np.full(len(TABLE), -1, np.int32))
    pts, lab = pred([(A, 0)])
    r, _ = evaluate_instances(pts, lab, np.array([1.0]), gt)
    assert math.isnan(r.ap50) and math.isnan(r.ap)


def test_merged_instance_halves_recall():
    pts, lab = pred([(A, 0), (B, 0)])  # both objects as one instance: IoU 0.5 with each
    r, m = evaluate_instances(pts, lab, np.array([1.0]), GT2)
    assert np.allclose(m.iou, [[0.5, 0.5]])
    assert r.ap25 == 50.0 and r.ap50 == 50.0  # one match at IoU exactly 0.5, recall 1/2
    assert dict(r.per_threshold)[0.55] == 0.0
    # unequal halves: IoU 10/25 with A -> below 0.5
    gt = make_gt([(A, 0), (cells(20, 35), 1)])
    pts, lab = pred([(A, 0), (cells(20, 35), 0)])
    r, _ = evaluate_instances(pts, lab, np.array([1.0]), gt)
    assert r.ap50 == 50.0 and r.ap25 == 50.0  # IoU 15/25 = 0.6 with the larger one
    assert dict(r.per_threshold)[0.65] == 0.0


def test_ids_and_their_order_do_not_matter():
    pts, lab = pred([(A, 0), (B, 1), (cells(60, 64), 2)])
    r1, _ = evaluate_instances(pts, lab, np.array([0.9, 0.5, 0.7]), GT2)
    relabel = np.array([5, 0, 2, 9, 1, 3])
    lab2 = relabel[lab]
    sc2 = np.zeros(10)
    sc2[[5, 0, 2]] = [0.9, 0.5, 0.7]
    r2, _ = evaluate_instances(pts[::-1], lab2[::-1], sc2, GT2)
    assert r1 == r2


def test_confidence_order_matters():
    bad = cells(60, 70)  # a false positive on nothing
    pts, lab = pred([(A, 0), (B, 1), (bad, 2)])
    first, _ = evaluate_instances(pts, lab, np.array([0.5, 0.4, 0.9]), GT2)
    last, _ = evaluate_instances(pts, lab, np.array([0.5, 0.4, 0.1]), GT2)
    assert last.ap50 == 100.0  # a false positive ranked after every true positive costs nothing
    assert first.ap50 == pytest.approx(100.0 * (0.5 * 2 / 3 + 0.5 * 2 / 3))  # precision 2/3 at both recalls
    assert first.ap50 < last.ap50


def test_predicted_background_counts_against_the_prediction():
    # prediction covers A and all of the table: IoU 10 / 20
    pts, lab = pred([(np.concatenate([A, TABLE]), 0), (B, 1)])
    r, m = evaluate_instances(pts, lab, np.array([1.0, 0.5]), GT2)
    assert m.iou.max(axis=1).tolist() == [0.5, 1.0]
    assert r.ap50 == 100.0 and dict(r.per_threshold)[0.55] == 25.0  # FP first, then TP: precision 1/2 at recall 1/2
    # cells the GT has no point in count too
    pts, lab = pred([(np.concatenate([A, cells(80, 90)]), 0)])
    _, m = evaluate_instances(pts, lab, np.array([1.0]), GT2)
    assert m.iou[0].tolist() == [0.5, 0.0]


def test_iou_threshold_edges():
    # IoU exactly 0.25, 0.5, 0.75 with A: prediction = A's first n cells
    for n, iou in ((3, 0.3), (5, 0.5), (10, 1.0)):
        pts, lab = pred([(cells(0, n), 0)])
        r, m = evaluate_instances(pts, lab, np.array([1.0]), GT2)
        assert m.iou[0, 0] == pytest.approx(iou)
        per = dict(r.per_threshold)
        for t, ap in per.items():
            assert ap == (50.0 if iou >= t - 1e-9 else 0.0), (n, t)
    # one prediction, two GT candidates above the threshold: it takes the higher IoU, one-to-one
    gt = make_gt([(cells(0, 10), 0), (cells(10, 14), 1)])
    pts, lab = pred([(cells(4, 14), 0), (cells(0, 4), 1)])  # IoU 0: 6/14 and 4/10; IoU 1: 4/10 with G0 only
    i25 = [0.25, *AP_THRESHOLDS].index(0.25)
    _, m = evaluate_instances(pts, lab, np.array([0.9, 0.8]), gt)
    assert np.allclose(m.iou, [[6 / 14, 4 / 10], [4 / 10, 0.0]])
    assert m.tp[i25].tolist() == [True, False]  # 0 took G0, so 1 has nothing left
    _, m = evaluate_instances(pts, lab, np.array([0.8, 0.9]), gt)
    assert m.tp[i25].tolist() == [True, True]  # 1 first takes G0, then 0 takes G1


def test_duplicate_prediction_is_false_positive():
    pts, lab = pred([(A, 0), (B, 1)])
    pts = np.concatenate([pts, A + 0.0001])
    lab = np.concatenate([lab, np.full(len(A), 2)])
    # the voxel of A now has two labels; majority breaks the tie to the lower id (0): the copy vanishes
    r, _ = evaluate_instances(pts, lab, np.array([0.9, 0.8, 0.7]), GT2)
    assert r.num_pred == 2 and r.ap50 == 100.0


def test_average_precision_step_curve_and_ties():
    assert average_precision(np.array([3.0, 2.0, 1.0]), np.array([True, False, True]), 2) == pytest.approx(
        0.5 * 1.0 + 0.5 * 2 / 3
    )
    # tied scores enter together: the order inside the tie does not matter
    a = average_precision(np.array([1.0, 1.0]), np.array([True, False]), 1)
    b = average_precision(np.array([1.0, 1.0]), np.array([False, True]), 1)
    assert a == b == 0.5
    assert math.isnan(average_precision(np.zeros(0), np.zeros(0, bool), 0))


@settings(max_examples=40, deadline=None)
@given(st.lists(st.tuples(st.floats(0, 1), st.booleans()), min_size=0, max_size=12), st.integers(1, 12))
def test_average_precision_bounds(rows, num_gt):
    s = np.array([r[0] for r in rows])
    tp = np.array([r[1] for r in rows], bool)
    if tp.sum() > num_gt:
        num_gt = int(tp.sum())
    ap = average_precision(s, tp, num_gt)
    assert 0.0 <= ap <= 1.0 + 1e-12
    assert ap <= tp.sum() / num_gt + 1e-12  # never above the final recall


@settings(max_examples=20, deadline=None)
@given(st.permutations(list(range(6))))
def test_relabelling_is_invariant(perm):
    rng = np.random.default_rng(0)
    objs = [cells(10 * i, 10 * i + 6) for i in range(5)]
    gt = make_gt([(o, i) for i, o in enumerate(objs)])
    lab = np.concatenate([np.full(len(o), i) for i, o in enumerate(objs)])
    lab[rng.random(len(lab)) < 0.2] = 5
    pts = np.concatenate(objs)
    sc = np.array([0.9, 0.9, 0.3, 0.5, 0.1, 0.7])
    r1, _ = evaluate_instances(pts, lab, sc, gt)
    p = np.array(perm)
    sc2 = np.empty(6)
    sc2[p] = sc
    r2, _ = evaluate_instances(pts, p[lab], sc2, gt)
    assert r1 == r2


def test_pooled_ap_over_scenes():
    pts, lab = pred([(A, 0), (B, 1)])
    _, good = evaluate_instances(pts, lab, np.array([0.9, 0.8]), GT2)
    _, empty = evaluate_instances(np.zeros((0, 3)), np.zeros(0, np.int32), np.zeros(0), GT2)
    r = pooled_ap([good, empty])
    assert r.ap50 == 50.0 and r.num_gt == 4


def test_bad_input():
    with pytest.raises(SceneError):
        evaluate_instances(A, np.full(len(A), 3), np.array([1.0]), GT2)


def test_semantic_iou():
    gt = make_gt([(A, 0), (B, 1), (cells(60, 70), 2)], categories=["mug", "banana", "mug"])
    pts = np.concatenate([A, B, TABLE])
    target_mug = np.zeros(len(pts), bool)
    target_mug[: len(A)] = True  # found one of the two mugs: 10 / 20
    target_banana = np.zeros(len(pts), bool)
    target_banana[len(A) : len(A) + 5] = True  # half of the banana
    target_banana[-5:] = True  # plus 5 table cells: 5 / 15
    r = semantic_iou(pts, [target_mug, target_banana], ["mug", "banana"], gt, seconds=1.5,
                     queries=["the mug", "a banana"])
    assert [q.iou for q in r.per_query] == pytest.approx([50.0, 100 / 3])
    assert r.mean_iou == pytest.approx((50.0 + 100 / 3) / 2)
    assert r.total_seconds == 1.5 and r.per_query[0].query == "the mug"
    with pytest.raises(SceneError):
        semantic_iou(pts, [target_mug], ["mug", "banana"], gt)


def test_stage_times_and_memory():
    t = stage_times([("a", 1.0), ("b", 0.5), ("a", 0.25)])
    assert t.stages == (("a", 1.25), ("b", 0.5)) and t.total == 1.75 and t.get("b") == 0.5
    with MemoryProbe() as m:
        x = np.ones(4_000_000)  # 32 MB
        del x
    assert m.peak_traced_mb >= 30 and m.maxrss_mb > 0


def test_thresholds():
    assert AP_THRESHOLDS[0] == 0.5 and AP_THRESHOLDS[-1] == 0.95 and len(AP_THRESHOLDS) == 10
