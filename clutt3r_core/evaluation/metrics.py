"""Evaluation metrics: class-agnostic 3D instance AP, language-grounded 3D semantic IoU, timing.

Both metrics compare prediction and ground truth on one regular **10 mm voxel grid**
(paper Sec. IV-A: "all over identical 10 mm voxel grids for fair comparison across all
methods"). The grid is anchored at the world origin (cell = floor(p / voxel)), so the
two sides fall on the same cells whatever points they come from. Each side is
voxelised on its own: a cell takes the **majority label** of that side's points in it
(ties: the lower label; -1 = background / none takes part in the vote like any label).

Instance AP (Sec. IV-A, ScanNet benchmark protocol, class-agnostic):

* IoU(p, g) = |P & G| / |P | G| over cells. A predicted cell on ground-truth
  background, or on a cell the ground truth has no point in, is in P but not in G,
  so it counts against the prediction (it enlarges the union).
* For each IoU threshold t: predictions sorted by descending confidence are matched
  greedily, one-to-one, to the still unmatched ground-truth instance of highest IoU
  with IoU >= t (a match needs IoU of at least t: an IoU of exactly 0.5 is a match at
  AP@50). Matched = true positive, otherwise false positive.
* The precision-recall curve is evaluated at every distinct confidence (tied
  predictions enter together, so their order does not matter), precision is made
  monotone (the running maximum from the high-recall end, as ScanNet / VOC "all
  points"), and AP is the area under that step curve over recall in [0, 1].
* Reported: AP@25, AP@50, and AP = mean over t in 0.50:0.05:0.95, all in percent.
  A scene with no ground-truth instance has undefined AP (NaN).

Ties in confidence are processed (for the matching) by descending predicted size,
then by the lowest cell index, so relabelling the instance ids never changes a result.
"""

from __future__ import annotations

import resource
import tracemalloc
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import GroundTruth

__all__ = [
    "EVAL_VOXEL",
    "AP_THRESHOLDS",
    "VoxelLabels",
    "voxelize_labels",
    "InstanceMatches",
    "APResult",
    "instance_iou",
    "union_cells",
    "match_instances",
    "average_precision",
    "evaluate_instances",
    "pooled_ap",
    "QueryIoU",
    "SemanticIoUResult",
    "semantic_iou",
    "StageTimes",
    "stage_times",
    "MemoryProbe",
]

EVAL_VOXEL = 0.01
"""Sec. IV-A: evaluation grid of 10 mm for every method."""

AP_THRESHOLDS: tuple[float, ...] = tuple(round(0.5 + 0.05 * i, 2) for i in range(10))
"""Sec. IV-A: "mean AP averaged over thresholds from 50% to 95% in 5% increments"."""


# ------------------------------------------------------------------ voxelisation


@dataclass(frozen=True, eq=False)
class VoxelLabels:
    """Majority labels of one side on the evaluation grid.

    Attributes:
        cells: (C, 3) int64 integer cell coordinates floor(p / voxel), sorted lexicographically.
        labels: (C,) int64 majority label per cell (-1 = background / none).
        voxel: cell edge in metres.
    """

    cells: np.ndarray
    labels: np.ndarray
    voxel: float

    def __post_init__(self) -> None:
        if self.cells.ndim != 2 or self.cells.shape[1] != 3 or self.labels.shape != (self.cells.shape[0],):
            raise SceneError(f"VoxelLabels: cells (C, 3) and labels (C,) must agree, got {self.cells.shape}, {self.labels.shape}")


def voxelize_labels(points: np.ndarray, labels: np.ndarray, voxel: float = EVAL_VOXEL) -> VoxelLabels:
    """Majority label of ``points`` (N, 3) metres per ``voxel`` cell; ``labels`` (N,) int, -1 = none."""
    p = np.asarray(points, np.float64).reshape(-1, 3)
    lab = np.asarray(labels, np.int64).reshape(-1)
    if p.shape[0] != lab.shape[0]:
        raise SceneError(f"voxelize_labels: {p.shape[0]} points but {lab.shape[0]} labels")
    if not voxel > 0:
        raise SceneError(f"voxelize_labels: voxel must be > 0, got {voxel}")
    if p.shape[0] == 0:
        return VoxelLabels(np.zeros((0, 3), np.int64), np.zeros(0, np.int64), float(voxel))
    if not np.all(np.isfinite(p)):
        raise SceneError("voxelize_labels: points contain NaN or inf")
    q = np.floor(p / voxel).astype(np.int64)
    cells, cell_of = np.unique(q, axis=0, return_inverse=True)
    cell_of = cell_of.reshape(-1)
    # count (cell, label) pairs, then keep the most frequent label of every cell
    pair = np.stack([cell_of, lab], axis=1)
    uniq, cnt = np.unique(pair, axis=0, return_counts=True)  # sorted by cell, then label
    # within a cell: highest count first, lower label on ties
    order = np.lexsort((uniq[:, 1], -cnt, uniq[:, 0]))
    uniq = uniq[order]
    first = np.ones(len(uniq), bool)
    first[1:] = uniq[1:, 0] != uniq[:-1, 0]
    out = np.empty(len(cells), np.int64)
    out[uniq[first, 0]] = uniq[first, 1]
    return VoxelLabels(cells, out, float(voxel))


def union_cells(pred: VoxelLabels, gt: VoxelLabels) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Both sides on the sorted union of their cells: (cells (U, 3), pred label (U,), gt label (U,),
    in_pred (U,) bool, in_gt (U,) bool). A cell missing on one side has label -1 there."""
    both = np.concatenate([pred.cells, gt.cells], axis=0).reshape(-1, 3)
    cells, inv = np.unique(both, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    u = len(cells)
    lp = np.full(u, -1, np.int64)
    lg = np.full(u, -1, np.int64)
    in_pred = np.zeros(u, bool)
    in_gt = np.zeros(u, bool)
    ip, ig = inv[: len(pred.cells)], inv[len(pred.cells) :]
    lp[ip], in_pred[ip] = pred.labels, True
    lg[ig], in_gt[ig] = gt.labels, True
    return cells.reshape(-1, 3), lp, lg, in_pred, in_gt


def _joint_cells(pred: VoxelLabels, gt: VoxelLabels) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(pred_label (U,), gt_label (U,), cell order key (U,)) on the union of both sides' cells
    (``union_cells``)."""
    _, lp, lg, _, _ = union_cells(pred, gt)
    return lp, lg, np.arange(len(lp))


# ------------------------------------------------------------------ instance AP


@dataclass(frozen=True, eq=False)
class InstanceMatches:
    """The outcome of greedy matching for every threshold, enough to pool AP over scenes.

    Attributes:
        thresholds: (T,) float64 IoU thresholds.
        scores: (P,) float64 confidences of the predictions in processing order.
        tp: (T, P) bool, prediction j is a true positive at threshold t.
        num_gt: number of ground-truth instances (cells-majority, non-empty).
        iou: (P, G) float64 IoU of every prediction (processing order) with every GT instance.
    """

    thresholds: np.ndarray
    scores: np.ndarray
    tp: np.ndarray
    num_gt: int
    iou: np.ndarray


@dataclass(frozen=True)
class APResult:
    """Class-agnostic instance AP of one scene (percent; NaN when the scene has no GT instance).

    Attributes:
        ap25: AP at IoU 0.25.
        ap50: AP at IoU 0.50.
        ap: mean AP over IoU 0.50:0.05:0.95.
        per_threshold: ((threshold, AP), ...) for 0.25 and every threshold of ``ap``.
        num_gt: ground-truth instances on the grid.
        num_pred: predicted instances on the grid (non-empty after voxelisation).
    """

    ap25: float
    ap50: float
    ap: float
    per_threshold: tuple[tuple[float, float], ...]
    num_gt: int
    num_pred: int


def instance_iou(pred: VoxelLabels, gt: VoxelLabels) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """IoU of every predicted with every GT instance on the grid.

    Returns (iou (P, G) float64, pred ids (P,), gt ids (G,), pred sizes (P,) in cells);
    ids are the labels >= 0 present on each side, ascending.
    """
    lp, lg, _ = _joint_cells(pred, gt)
    return _iou_on_joint(lp, lg)


def _iou_on_joint(lp: np.ndarray, lg: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """``instance_iou`` from both sides' labels on their joint cells (``_joint_cells``)."""
    pid = np.unique(lp[lp >= 0])
    gid = np.unique(lg[lg >= 0])
    pi = np.searchsorted(pid, lp)
    gi = np.searchsorted(gid, lg)
    psize = np.bincount(pi[lp >= 0], minlength=len(pid)).astype(np.float64)
    gsize = np.bincount(gi[lg >= 0], minlength=len(gid)).astype(np.float64)
    both = (lp >= 0) & (lg >= 0)
    inter = np.zeros((len(pid), len(gid)), np.float64)
    np.add.at(inter, (pi[both], gi[both]), 1.0)
    union = psize[:, None] + gsize[None, :] - inter
    iou = np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
    return iou, pid, gid, psize


def match_instances(
    pred: VoxelLabels,
    pred_scores: dict[int, float] | np.ndarray,
    gt: VoxelLabels,
    thresholds: Sequence[float] = (0.25, *AP_THRESHOLDS),
) -> InstanceMatches:
    """Greedy one-to-one matching at each threshold (module docstring).

    ``pred_scores``: confidence of each predicted id, as an array indexed by id or a dict.
    """
    lp, lg, key = _joint_cells(pred, gt)  # once: the union of the cells is most of the cost
    iou, pid, _gid, psize = _iou_on_joint(lp, lg)
    s = np.array([float(pred_scores[int(i)]) for i in pid], np.float64)
    # tie-break independent of ids: larger prediction first, then its first cell
    first_cell = np.full(len(pid), np.iinfo(np.int64).max)
    if len(pid):
        idx = np.searchsorted(pid, lp[lp >= 0])
        np.minimum.at(first_cell, idx, key[lp >= 0])
    order = np.lexsort((first_cell, -psize, -s))
    iou, s = iou[order], s[order]
    th = np.asarray(thresholds, np.float64)
    tp = np.zeros((len(th), len(s)), bool)
    g = iou.shape[1]
    for t_i, t in enumerate(th):
        free = np.ones(g, bool)
        for j in range(len(s)):  # sequential by nature (greedy); P is tens, not points
            cand = np.where(free & (iou[j] >= t - 1e-12), iou[j], -1.0)
            if g and cand.max() >= 0:
                k = int(np.argmax(cand))
                free[k] = False
                tp[t_i, j] = True
    return InstanceMatches(th, s, tp, int(g), iou)


def average_precision(scores: np.ndarray, tp: np.ndarray, num_gt: int) -> float:
    """Area under the monotone precision-recall step curve, in [0, 1]; NaN if ``num_gt`` is 0.

    ``scores`` (P,) and ``tp`` (P,) bool in any order; predictions with equal scores enter together.
    """
    if num_gt <= 0:
        return float("nan")
    scores = np.asarray(scores, np.float64)
    tp = np.asarray(tp, bool)
    if len(scores) == 0:
        return 0.0
    order = np.argsort(-scores, kind="stable")
    scores, tp = scores[order], tp[order]
    ctp = np.cumsum(tp)
    cfp = np.cumsum(~tp)
    # evaluate only at the end of each block of tied scores
    last = np.ones(len(scores), bool)
    last[:-1] = scores[1:] != scores[:-1]
    ctp, cfp = ctp[last], cfp[last]
    recall = ctp / num_gt
    precision = ctp / np.maximum(ctp + cfp, 1)
    precision = np.maximum.accumulate(precision[::-1])[::-1]  # monotone envelope
    r = np.concatenate([[0.0], recall])
    return float(np.sum((r[1:] - r[:-1]) * precision))


def _ap_from_matches(m: InstanceMatches) -> dict[float, float]:
    return {float(t): 100.0 * average_precision(m.scores, m.tp[i], m.num_gt) for i, t in enumerate(m.thresholds)}


def _summarise(per: dict[float, float], num_gt: int, num_pred: int) -> APResult:
    def at(t: float) -> float:
        return per[min(per, key=lambda x: abs(x - t))]

    main = [at(t) for t in AP_THRESHOLDS]
    return APResult(
        ap25=at(0.25),
        ap50=at(0.50),
        ap=float(np.mean(main)) if num_gt else float("nan"),
        per_threshold=tuple(sorted((round(t, 2), v) for t, v in per.items())),
        num_gt=num_gt,
        num_pred=num_pred,
    )


def evaluate_instances(
    points: np.ndarray,
    instance: np.ndarray,
    scores: np.ndarray,
    gt: GroundTruth,
    voxel: float = EVAL_VOXEL,
) -> tuple[APResult, InstanceMatches]:
    """Class-agnostic instance AP of one prediction against ``gt`` (module docstring).

    points: (N, 3) predicted points, metres; instance: (N,) int id per point, -1 = none;
    scores: (K,) confidence of instance k (ids index into it).
    """
    inst = np.asarray(instance, np.int64).reshape(-1)
    sc = np.asarray(scores, np.float64).reshape(-1)
    if inst.size and inst.max() >= len(sc):
        raise SceneError(f"evaluate_instances: instance id {int(inst.max())} has no score ({len(sc)} scores)")
    if inst.size and inst.min() < -1:
        raise SceneError("evaluate_instances: instance ids must be >= -1")
    pv = voxelize_labels(points, inst, voxel)
    gv = voxelize_labels(gt.points, gt.point_labels, voxel)
    m = match_instances(pv, sc, gv)
    return _summarise(_ap_from_matches(m), m.num_gt, len(m.scores)), m


def pooled_ap(matches: Sequence[InstanceMatches]) -> APResult:
    """AP over several scenes pooled into one ranking (the ScanNet benchmark's dataset-level AP)."""
    if not matches:
        raise SceneError("pooled_ap: no scenes")
    th = matches[0].thresholds
    scores = np.concatenate([m.scores for m in matches])
    tp = np.concatenate([m.tp for m in matches], axis=1)
    n = int(sum(m.num_gt for m in matches))
    per = {float(t): 100.0 * average_precision(scores, tp[i], n) for i, t in enumerate(th)}
    return _summarise(per, n, len(scores))


# ------------------------------------------------------------------ semantic IoU


@dataclass(frozen=True)
class QueryIoU:
    """IoU of one category query: ``query`` text, ``category`` evaluated, ``iou`` in percent."""

    query: str
    category: str
    iou: float


@dataclass(frozen=True)
class SemanticIoUResult:
    """Language-grounded 3D semantic segmentation (paper Table II).

    Attributes:
        per_query: IoU of every query.
        mean_iou: mean over queries, percent (NaN without queries).
        total_seconds: query time summed over all queries (Table II "Time").
    """

    per_query: tuple[QueryIoU, ...]
    mean_iou: float
    total_seconds: float


def semantic_iou(
    points: np.ndarray,
    target_masks: Sequence[np.ndarray],
    categories: Sequence[str],
    gt: GroundTruth,
    seconds: float = 0.0,
    queries: Sequence[str] | None = None,
    voxel: float = EVAL_VOXEL,
) -> SemanticIoUResult:
    """3D IoU of predicted targets with the GT voxels of each queried category.

    points: (N, 3) metres; target_masks[q]: (N,) bool, the points the method returned for
    query q; categories[q]: the GT category that query names (``ObjectInfo.category``);
    seconds: total time the method spent on all queries. A cell is a target when most of
    its points are; a GT cell belongs to the category when its majority object does.
    """
    if len(target_masks) != len(categories):
        raise SceneError(f"semantic_iou: {len(target_masks)} masks but {len(categories)} categories")
    queries = list(queries) if queries is not None else list(categories)
    cat_of = np.array([o.category for o in gt.objects] + [""], dtype=object)
    gv = voxelize_labels(gt.points, gt.point_labels, voxel)
    out = []
    for q, cat, mask in zip(queries, categories, target_masks):
        mask = np.asarray(mask, bool).reshape(-1)
        if mask.shape[0] != np.asarray(points).reshape(-1, 3).shape[0]:
            raise SceneError(f"semantic_iou: target mask of query '{q}' has {mask.shape[0]} entries, points {len(points)}")
        pv = voxelize_labels(points, mask.astype(np.int64) - 1, voxel)  # 0 = target, -1 = not
        g_is = np.array([cat_of[i] == cat for i in gv.labels], bool) if len(gv.labels) else np.zeros(0, bool)
        g_lab = VoxelLabels(gv.cells, np.where(g_is, 0, -1), voxel)
        lp, lg, _ = _joint_cells(pv, g_lab)
        inter = float(np.sum((lp == 0) & (lg == 0)))
        union = float(np.sum((lp == 0) | (lg == 0)))
        out.append(QueryIoU(q, cat, 100.0 * inter / union if union > 0 else 0.0))
    mean = float(np.mean([x.iou for x in out])) if out else float("nan")
    return SemanticIoUResult(tuple(out), mean, float(seconds))


# ------------------------------------------------------------------ time and memory


@dataclass(frozen=True)
class StageTimes:
    """Seconds per named stage of one run, in pipeline order; ``total`` is their sum."""

    stages: tuple[tuple[str, float], ...]

    @property
    def total(self) -> float:
        return float(sum(s for _, s in self.stages))

    def get(self, stage: str) -> float:
        return float(sum(s for n, s in self.stages if n == stage))


def stage_times(timings: Sequence) -> StageTimes:
    """StageTimes from ``Segmentation.trace.timings`` (StageTiming objects) or (name, seconds) pairs."""
    out: dict[str, float] = {}
    for t in timings:
        name, sec = (t.stage, t.seconds) if hasattr(t, "stage") else (t[0], t[1])
        out[str(name)] = out.get(str(name), 0.0) + float(sec)
    return StageTimes(tuple(out.items()))


@dataclass
class MemoryProbe:
    """Peak memory of a block of code: ``with MemoryProbe() as m: ...`` then ``m.peak_traced_mb``
    (tracemalloc: Python and numpy allocations made inside the block) and ``m.maxrss_mb``
    (the process's resident-set high-water mark so far; in a worker process this is the
    worker's peak over every job it ran, an upper bound for the block)."""

    trace: bool = True
    peak_traced_mb: float = field(default=float("nan"))
    maxrss_mb: float = field(default=float("nan"))
    _started: bool = field(default=False, repr=False)

    def __enter__(self) -> "MemoryProbe":
        if self.trace and not tracemalloc.is_tracing():
            tracemalloc.start()
            self._started = True
        if tracemalloc.is_tracing():
            tracemalloc.reset_peak()
        return self

    def __exit__(self, *exc) -> None:
        if tracemalloc.is_tracing():
            self.peak_traced_mb = tracemalloc.get_traced_memory()[1] / 2**20
            if self._started:
                tracemalloc.stop()
        self.maxrss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # kB on Linux
