"""The naive baseline: back-project every mask, merge masks across views by 3D voxel IoU.

Every usable mask (``common.mask_evidence``) is its set of voxels. Two masks of
different views whose voxel IoU is at least ``iou_threshold`` are linked, and the
connected components of that graph (union-find) are the instances. Voxels go to the
component with the most masks covering them; score = number of masks.

Why the threshold is 0.25 (ours): two views of one object see different surfaces, so
even a perfect pair of masks of one object shares only part of its voxels (findings
point 3: same-object similarity has a median around 0.4 on 5 mm voxels). 0.25 links most
same-object pairs; higher values leave objects split into per-view fragments, lower ones
chain neighbours. This is the "naive yardstick" of shared/notes/grouping-findings.md.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from clutt3r_core.baselines.common import MaskEvidence, Prediction, run_baseline
from clutt3r_core.scene import Scene

__all__ = ["NaiveConfig", "naive_groups", "naive_baseline"]


@dataclass(frozen=True)
class NaiveConfig:
    """Naive 3D-IoU mask merging (ours, a yardstick; no paper)."""

    iou_threshold: float = 0.25
    """Voxel IoU at or above which two masks of different views are linked (module doc)."""
    cross_view_only: bool = True
    """Link only masks of different views (two masks of a view overlap when one is a part of the other)."""
    min_instance_points: int = 30
    """Same speck filter as our vote (VoteConfig.min_instance_points)."""


def voxel_iou(voxels: sp.csr_matrix) -> np.ndarray:
    """(M, M) float64 IoU of the voxel sets of all masks (rows of a 0/1 CSR matrix)."""
    inter = (voxels @ voxels.T).toarray().astype(np.float64)
    size = np.asarray(voxels.sum(axis=1)).ravel().astype(np.float64)
    union = size[:, None] + size[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def naive_groups(ev: MaskEvidence, cfg: NaiveConfig = NaiveConfig()) -> list[list[int]]:
    """Connected components (lists of mask indices, sorted) of the IoU graph over non-background masks."""
    use = np.flatnonzero(~ev.background)
    if len(use) == 0:
        return []
    iou = voxel_iou(ev.voxels[use])
    link = iou >= cfg.iou_threshold
    if cfg.cross_view_only:
        link &= ev.view[use][:, None] != ev.view[use][None, :]
    ncomp, comp = connected_components(sp.csr_matrix(link), directed=False)
    groups = [sorted(use[comp == c].tolist()) for c in range(ncomp)]
    return sorted(groups, key=lambda g: g[0])


def naive_baseline(scene: Scene, cfg: NaiveConfig = NaiveConfig()) -> Prediction:
    """Naive baseline on ``scene``'s initial views (module docstring)."""
    return run_baseline(scene, "naive", lambda ev: naive_groups(ev, cfg), cfg.min_instance_points)
