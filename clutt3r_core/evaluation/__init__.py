"""Evaluation: metrics (instance AP, semantic IoU, timing, memory) and the benchmark runner.

``metrics`` is imported eagerly; the runner (``clutt3r bench``) lives in ``runner``.
"""

from clutt3r_core.evaluation.metrics import (  # noqa: F401
    AP_THRESHOLDS,
    EVAL_VOXEL,
    APResult,
    InstanceMatches,
    SemanticIoUResult,
    evaluate_instances,
    pooled_ap,
    semantic_iou,
)
