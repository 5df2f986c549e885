"""Where a scene's strict-IoU AP goes: an error breakdown on the evaluation grid (issue 13).

AP over IoU 0.50:0.95 punishes every wrongly labelled 10 mm cell of an object, so a
scene's AP alone does not say what to fix. This module labels every wrong cell with one
cause and measures, for each cause, how many AP points an oracle that fixes only that
cause would give back. Pure functions over ``metrics.VoxelLabels``; same grid, same
majority voxelisation and same matching as ``metrics.evaluate_instances``.

Definitions (P = predicted instances, G = GT objects, both on the 10 mm grid):

* dominant GT of a prediction p: the label (a GT object, or -1 = GT background / no GT
  point) holding most of p's cells (ties: the lower label);
* own prediction of a GT object g: among the predictions whose dominant GT is g, the one
  with the most cells on g; g has none when no prediction is dominated by it;
* fragment: a prediction whose dominant GT is g but that is not g's own prediction (a
  piece of an object another prediction already covers most of);
* spurious: a prediction whose dominant GT is -1 (mostly table or off the GT surface).

Every cell has a target: the own prediction of its GT object (or -1 on GT background /
without a GT point, or for an object with no own prediction, see *merged*). A cell whose
prediction differs from its target is wrong, of exactly one kind, tested in this order.
Two kinds are the sensor's, which no labelling can fix:

1. ``hole``: a GT object cell where the fused cloud has no point (depth holes at edges and
   grazing angles, too few raw points for a fused voxel);
2. ``off_gt``: a predicted object cell where the GT has no point (the noisy surface spills
   into neighbouring cells, flying pixels: a perfect labelling of the noisy cloud pays these
   too).

The others are the labelling's:

3. ``fragment``: a cell of g labelled by a fragment of g;
4. ``boundary``: within one cell (26-neighbourhood) of a GT cell of another label: the
   object's rim, its contact with the table or a neighbour;
5. ``missing``: a cell of g left unlabelled (a missing object part);
6. ``merged``: a cell of g labelled by a prediction of another object (merged neighbours;
   also every cell of an object with no own prediction that some prediction covers);
7. ``table``: a GT-background cell (table, tray) labelled as an object.

The AP an oracle gives back for a kind: that kind's wrong cells set to their target (a hole
gets a labelled cell, an off-GT cell is left unlabelled) (an
object with no own prediction gets a new instance with the score of the prediction that
held most of it), AP recomputed; ``ap_gain`` is the difference. Gains of several kinds do
not add up exactly (AP is not linear), but each isolates one cause.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation.metrics import (
    AP_THRESHOLDS,
    EVAL_VOXEL,
    VoxelLabels,
    _ap_from_matches,
    _summarise,
    match_instances,
    union_cells,
    voxelize_labels,
)
from clutt3r_core.scene import GroundTruth

__all__ = ["ERROR_KINDS", "SENSOR_KINDS", "ErrorBreakdown", "error_breakdown", "breakdown_from_cells"]

ERROR_KINDS: tuple[str, ...] = ("hole", "off_gt", "fragment", "boundary", "missing", "merged", "table")
"""Kinds of wrong cells, in the order a cell is tested (module docstring)."""
SENSOR_KINDS: tuple[str, ...] = ("hole", "off_gt")
"""Kinds no labelling of the fused cloud can fix."""


@dataclass(frozen=True)
class ErrorBreakdown:
    """Where one scene's strict-IoU AP is lost (module docstring).

    Attributes:
        num_gt: GT objects on the grid.
        num_pred: predicted instances on the grid.
        num_fragments: predictions that are a piece of an object another prediction covers most of.
        num_spurious: predictions mostly on GT background or off the GT surface.
        num_merged_objects: GT objects with no own prediction, most of whose cells a prediction of
            another object holds.
        num_missed_objects: GT objects with no own prediction, most of whose cells are unlabelled.
        gt_cells: cells of GT objects (the denominator of ``cell_fraction``).
        wrong_cells: wrong cells of each kind, aligned with ``ERROR_KINDS``.
        ap: the scene's AP over IoU 0.50:0.95, percent.
        ap_gain: AP points an oracle fixing only that kind gives back, aligned with ``ERROR_KINDS``.
        ap_all_fixed: AP with every labelling kind fixed (all but ``SENSOR_KINDS``): a perfect
            labelling of the fused cloud, the ceiling the depth noise and the fusion leave.
    """

    num_gt: int
    num_pred: int
    num_fragments: int
    num_spurious: int
    num_merged_objects: int
    num_missed_objects: int
    gt_cells: int
    wrong_cells: tuple[int, ...]
    ap: float
    ap_gain: tuple[float, ...]
    ap_all_fixed: float

    def __post_init__(self) -> None:
        if len(self.wrong_cells) != len(ERROR_KINDS) or len(self.ap_gain) != len(ERROR_KINDS):
            raise SceneError(f"ErrorBreakdown: wrong_cells and ap_gain need {len(ERROR_KINDS)} entries ({ERROR_KINDS})")

    def cell_fraction(self, kind: str) -> float:
        """Wrong cells of ``kind`` per GT object cell (0..; ``table`` / ``off_gt`` may exceed 1 in theory)."""
        return self.wrong_cells[ERROR_KINDS.index(kind)] / max(self.gt_cells, 1)

    def gain(self, kind: str) -> float:
        return self.ap_gain[ERROR_KINDS.index(kind)]

    def to_json(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}

    @staticmethod
    def from_json(d: dict) -> "ErrorBreakdown":
        d = dict(d)
        d["wrong_cells"] = tuple(int(x) for x in d["wrong_cells"])
        d["ap_gain"] = tuple(float(x) for x in d["ap_gain"])
        return ErrorBreakdown(**d)


def error_breakdown(
    points: np.ndarray, instance: np.ndarray, scores: np.ndarray, gt: GroundTruth, voxel: float = EVAL_VOXEL
) -> ErrorBreakdown:
    """Breakdown of one prediction (arguments as ``metrics.evaluate_instances``)."""
    inst = np.asarray(instance, np.int64).reshape(-1)
    sc = np.asarray(scores, np.float64).reshape(-1)
    if inst.size and inst.max() >= len(sc):
        raise SceneError(f"error_breakdown: instance id {int(inst.max())} has no score ({len(sc)} scores)")
    return breakdown_from_cells(voxelize_labels(points, inst, voxel), sc,
                                voxelize_labels(gt.points, gt.point_labels, voxel))


def _near_other_label(cells: np.ndarray, lg: np.ndarray, in_gt: np.ndarray) -> np.ndarray:
    """(U,) bool: a GT cell of another label (or, for a cell without GT, of two labels) lies in its 26-neighbourhood."""
    u = len(cells)
    if u == 0:
        return np.zeros(0, bool)
    lo = cells.min(axis=0) - 1
    dims = cells.max(axis=0) - lo + 2
    def key(c: np.ndarray) -> np.ndarray:
        c = c - lo
        return (c[:, 0] * dims[1] + c[:, 1]) * dims[2] + c[:, 2]
    gkeys = key(cells[in_gt])
    order = np.argsort(gkeys)
    gkeys, glab = gkeys[order], lg[in_gt][order]
    own = np.where(in_gt, lg, np.iinfo(np.int64).min)  # a cell without GT: "no label" of its own
    first = np.full(u, np.iinfo(np.int64).min)  # the first GT label seen around a cell without GT
    near = np.zeros(u, bool)
    for off in np.array(np.meshgrid([-1, 0, 1], [-1, 0, 1], [-1, 0, 1], indexing="ij")).reshape(3, -1).T:
        if not off.any():
            continue
        k = key(cells + off)
        i = np.minimum(np.searchsorted(gkeys, k), len(gkeys) - 1)
        hit = gkeys[i] == k if len(gkeys) else np.zeros(u, bool)
        lab = glab[i] if len(gkeys) else np.zeros(u, np.int64)
        near |= hit & in_gt & (lab != own)
        unseen = hit & ~in_gt
        near |= unseen & (first != np.iinfo(np.int64).min) & (lab != first)
        first = np.where(unseen & (first == np.iinfo(np.int64).min), lab, first)
    return near


def _ap(labels: np.ndarray, cells: np.ndarray, scores: np.ndarray, gt: VoxelLabels) -> float:
    """AP over IoU 0.50:0.95 (percent) of labels (U,) on cells (U, 3); NaN without GT objects."""
    pv = VoxelLabels(cells, labels, gt.voxel)
    m = match_instances(pv, scores, gt, thresholds=AP_THRESHOLDS)
    # the same averaging as the reported AP (metrics._summarise), so an oracle's gain is in the report's units
    return _summarise(_ap_from_matches(m), m.num_gt, len(m.scores)).ap


def breakdown_from_cells(pred: VoxelLabels, scores: np.ndarray, gt: VoxelLabels) -> ErrorBreakdown:
    """Breakdown from both sides' majority labels on the grid; ``scores`` (K,) confidence of prediction id k."""
    if pred.voxel != gt.voxel:
        raise SceneError(f"breakdown_from_cells: grids differ ({pred.voxel} vs {gt.voxel} m)")
    scores = np.asarray(scores, np.float64).reshape(-1)
    cells, lp, lg, in_pred, in_gt = union_cells(pred, gt)
    pid = np.unique(lp[lp >= 0])
    gid = np.unique(lg[lg >= 0])
    npred, ngt = len(pid), len(gid)
    # contingency: rows predictions, columns GT objects plus one "background / no GT" column
    pi = np.searchsorted(pid, lp)
    gi = np.where(lg >= 0, np.searchsorted(gid, lg), ngt)
    cont = np.zeros((npred, ngt + 1), np.int64)
    np.add.at(cont, (pi[lp >= 0], gi[lp >= 0]), 1)
    # dominant GT; ties go to the lower label, background (-1) being the lowest
    dom_col = np.argmax(np.concatenate([cont[:, ngt:], cont[:, :ngt]], axis=1), axis=1) - 1 if npred else np.zeros(0, int)
    spurious = dom_col < 0
    own = np.full(ngt, -1, np.int64)  # index into pid
    for g in range(ngt):
        cand = np.flatnonzero(dom_col == g)
        if len(cand):
            own[g] = cand[np.argmax(cont[cand, g])]
    fragment = np.zeros(npred, bool)
    fragment[(dom_col >= 0)] = True
    fragment[own[own >= 0]] = False
    fragment &= ~spurious

    # target label of every cell
    target = np.full(len(cells), -1, np.int64)
    on_obj = lg >= 0
    own_id = np.full(ngt, -1, np.int64)
    own_id[own >= 0] = pid[own[own >= 0]]
    target[on_obj] = own_id[gi[on_obj]]
    # an object without an own prediction: a new instance (oracle), scored like the prediction holding most of it
    next_id = (int(pid.max()) + 1) if npred else 0
    oracle_scores = list(scores) + [0.0] * max(0, next_id - len(scores))
    merged_obj = missed_obj = 0
    gsize = np.bincount(gi[on_obj], minlength=ngt)
    for g in np.flatnonzero(own < 0):
        held = cont[:, g]
        if npred and held.max() * 2 > gsize[g]:
            merged_obj += 1
        else:
            missed_obj += 1
        target[on_obj & (gi == g)] = next_id
        oracle_scores.append(float(scores[pid[int(np.argmax(held))]]) if npred and held.max() > 0 else 0.0)
        next_id += 1
    oracle_scores_a = np.asarray(oracle_scores, np.float64)

    wrong = (lp != target) & (in_pred | on_obj)
    frag_lab = np.zeros(next_id + 1, bool)
    frag_lab[pid[fragment]] = True
    near = _near_other_label(cells, lg, in_gt)
    kind = np.full(len(cells), -1, np.int8)
    rest = wrong.copy()

    def assign(mask: np.ndarray, k: str) -> None:
        nonlocal rest
        m = rest & mask
        kind[m] = ERROR_KINDS.index(k)
        rest &= ~m

    assign(on_obj & ~in_pred, "hole")
    assign(~in_gt & (lp >= 0), "off_gt")
    if npred:
        assign(on_obj & (lp >= 0) & frag_lab[np.maximum(lp, 0)] & (dom_col[np.minimum(pi, npred - 1)] == lg), "fragment")
    assign(near, "boundary")
    assign(on_obj & (lp < 0), "missing")
    assign(on_obj & (lp >= 0), "merged")
    assign(in_gt & ~on_obj & (lp >= 0), "table")
    counts = tuple(int(np.sum(kind == i)) for i in range(len(ERROR_KINDS)))

    # cells outside the prediction carry -1, which the matching ignores: every AP is over all cells
    base = _ap(lp, cells, oracle_scores_a, gt)
    gains = tuple(_ap(np.where(kind == i, target, lp), cells, oracle_scores_a, gt) - base for i in range(len(ERROR_KINDS)))
    ap_all = _ap(np.where((kind >= 0) & ~np.isin(kind, [ERROR_KINDS.index(k) for k in SENSOR_KINDS]), target, lp), cells, oracle_scores_a, gt)
    return ErrorBreakdown(
        num_gt=ngt, num_pred=npred, num_fragments=int(fragment.sum()), num_spurious=int(spurious.sum()),
        num_merged_objects=merged_obj, num_missed_objects=missed_obj, gt_cells=int(on_obj.sum()),
        wrong_cells=counts, ap=float(base), ap_gain=tuple(float(x) for x in gains), ap_all_fixed=float(ap_all),
    )
