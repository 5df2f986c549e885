"""Baselines evaluated against our method on the same fused cloud and the same mask candidates.

* ``naive``: merge masks across views by 3D voxel IoU (``naive.py``).
* ``maskclustering``: a re-implementation from the published description of MaskClustering
  (Yan et al., CVPR 2024), view-consensus mask-graph clustering (``maskclustering.py``).

Each is a function ``Scene -> Prediction`` (``common.Prediction``: points, instance per
point, scores, stage timings), the same form ``segmentation_prediction`` gives our method.
"""

from clutt3r_core.baselines.common import MaskEvidence, Prediction, assign_by_majority, mask_evidence
from clutt3r_core.baselines.maskclustering import MaskClusteringConfig, maskclustering_baseline
from clutt3r_core.baselines.naive import NaiveConfig, naive_baseline

__all__ = [
    "Prediction",
    "MaskEvidence",
    "mask_evidence",
    "assign_by_majority",
    "NaiveConfig",
    "naive_baseline",
    "MaskClusteringConfig",
    "maskclustering_baseline",
    "segmentation_prediction",
]


def segmentation_prediction(seg, method: str = "ours") -> Prediction:
    """Our pipeline's ``Segmentation`` as a ``Prediction``."""
    return Prediction(seg.points, seg.instance, seg.scores, tuple(seg.trace.timings), method)
