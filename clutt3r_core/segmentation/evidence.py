"""Rules on what the grouping is fed, shared by the pipeline and the baselines.

One home for each, so that our method and the baselines cannot drift apart:

* ``check_views``: a scene can be segmented (initial views with depth and mask candidates);
* ``background_masks``: which masks are background (mostly on the table / tray) and are
  never grouped.

The minimum mask area lives with the instance trees (``trees.min_mask_area``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Scene

if TYPE_CHECKING:  # occupancy imports the segmentation package
    from clutt3r_core.occupancy import VoxelHits

__all__ = ["check_views", "background_masks"]


def check_views(scene: Scene, masks: bool = True) -> None:
    """Raise ``SceneError`` unless every initial view of ``scene`` has depth and (unless
    ``masks=False``: checked before candidates are generated) mask candidates."""
    if not scene.initial:
        demoted = [w.frame for w in scene.warnings if w.code == "frame-demoted"]
        why = f" (frames {demoted} have no depth file, so they were taken as post-interaction)" if demoted else ""
        raise SceneError(f"{scene.name or 'scene'}: no initial views to segment{why}")
    for v in scene.initial_views:
        if v.depth is None:
            raise SceneError(f"{v.name or v.frame}: initial view has no depth")
        if masks and v.masks is None:
            raise SceneError(
                f"{v.name or v.frame}: initial view has no mask candidates (segment(scene) with the "
                "default masks='auto' generates them with the builtin generator; or "
                "clutt3r_core.masks.ensure_candidates(scene, 'builtin'))"
            )


def background_masks(hits: VoxelHits, support_voxel: np.ndarray, fraction: float) -> np.ndarray:
    """(M,) bool: mask m is background.

    ``hits``: (M, N) pixels of mask m that fed voxel n (``occupancy.mask_voxel_hits``);
    ``support_voxel``: (N,) bool, voxel on a support super-voxel; ``fraction``:
    ``SegmentConfig.background_fraction``.

    A mask is background when more than ``fraction`` of its back-projected pixels (its 3D
    points) fed support voxels, or when none of its pixels fed any voxel: such a mask has
    no 3D evidence at all (all its depth is missing or out of range), so it can neither
    vote for a super-voxel nor be told apart from another mask in space, yet grouped it
    would still take its view's slot in a group and count towards the group's size.
    Pixel-weighted (not per voxel) because a voxel fed by one stray pixel at an object's
    edge must not weigh as much as one the mask covers fully.
    """
    if hits.shape[0] == 0:
        return np.zeros(0, bool)
    total = hits.row_sums()  # integer pixel counts: exact
    on_support = hits.matvec(support_voxel)
    return (on_support > fraction * total) | (total == 0)
