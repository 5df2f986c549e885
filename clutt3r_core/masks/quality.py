"""How good a view's candidates are against ground truth or another candidate set.

Used by ``benchmarks/bench_masks.py`` and the tests: recall of ground-truth objects by
their best candidate (IoU), candidates per view, and the share of parents and leaves in
the view's containment forest (built with the pipeline's own ``build_instance_tree``,
so "parent" and "leaf" mean what they mean to the method).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.scene import MaskCandidates
from clutt3r_core.segmentation.trees import TreeConfig, build_instance_tree

__all__ = ["ViewMaskQuality", "mask_iou_matrix", "view_quality", "leaf_masks"]


def mask_iou_matrix(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(A, B) float64 IoU between two stacks of (H, W) bool masks (same H, W)."""
    A = np.asarray(a, bool).reshape(len(a), -1).astype(np.float32)
    B = np.asarray(b, bool).reshape(len(b), -1).astype(np.float32)
    if len(A) == 0 or len(B) == 0:
        return np.zeros((len(A), len(B)))
    inter = (A @ B.T).astype(np.float64)
    union = A.sum(1)[:, None] + B.sum(1)[None, :] - inter
    return inter / np.maximum(union, 1.0)


@dataclass(frozen=True)
class ViewMaskQuality:
    """Candidates of one view against its ground-truth instance map.

    Attributes:
        best_iou: (K,) float64 best candidate IoU of each visible GT object (>= ``min_px`` pixels).
        num_candidates: candidates in the view.
        num_parents: candidates that contain another (inner nodes of the containment forest).
        num_leaves: candidates that contain none.
    """

    best_iou: np.ndarray
    num_candidates: int
    num_parents: int
    num_leaves: int

    def recall(self, iou: float) -> float:
        return float((self.best_iou >= iou).mean()) if len(self.best_iou) else float("nan")


def view_quality(cands: MaskCandidates, gt_map: np.ndarray, min_px: int = 100) -> ViewMaskQuality:
    """Quality of ``cands`` against a (H, W) int GT map (-1 = background); objects with fewer
    than ``min_px`` visible pixels are not counted (nothing can segment a sliver)."""
    ids, counts = np.unique(gt_map[gt_map >= 0], return_counts=True)
    ids = ids[counts >= min_px]
    gt = gt_map[None] == ids[:, None, None] if len(ids) else np.zeros((0, *gt_map.shape), bool)
    iou = mask_iou_matrix(gt, cands.masks)
    best = iou.max(axis=1) if iou.shape[1] else np.zeros(len(ids))
    tree = build_instance_tree(cands, 0, TreeConfig())
    has_child = np.zeros(len(tree.mask_ids), bool)
    has_child[tree.parent[tree.parent >= 0]] = True
    return ViewMaskQuality(best, len(cands), int(has_child.sum()), int((~has_child).sum()))


def leaf_masks(cands: MaskCandidates) -> np.ndarray:
    """(L, H, W) the leaves of a view's containment forest (the method's proper-segment candidates)."""
    tree = build_instance_tree(cands, 0, TreeConfig())
    has_child = np.zeros(len(tree.mask_ids), bool)
    has_child[tree.parent[tree.parent >= 0]] = True
    keep = [cands.index_of(int(i)) for i in tree.mask_ids[~has_child]]
    return cands.masks[keep]
