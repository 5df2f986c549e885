"""Scene update from one post-interaction image (Sec. III-C): registry kind ``pose_optimizer``.

The stages, each a pure function over typed data:

1. ``associate`` (associate.py): the new view's mask tree is matched to the stored
   instances (hierarchy-based: leaves first, spatial then semantic, parent substitution);
   unmatched instances are removed or occluded, unmatched masks new.
2. change detection (update.py): projected IoU with a z-buffer against the new mask,
   below tau_IoU = displaced.
3. ``PoseOptimizer.optimize(PoseProblem) -> PoseResult`` (pose.py, torch on the CPU):
   the rigid motion of each displaced instance.
4. ``apply_update`` / ``save_state`` (state.py): the new scene state, history kept, chained.

``update_scene(state, view)`` runs 1-3 and returns an ``UpdateResult`` (``update.json``);
``UpdateFrame`` is what the viewer replays for one post-interaction frame.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, Protocol, runtime_checkable

import numpy as np

from clutt3r_core.scene import Camera
from clutt3r_core.update.types import (
    STATUSES,
    AssociationConfig,
    ChangeConfig,
    InstanceUpdate,
    NewInstance,
    NewMask,
    PoseConfig,
    PoseProblem,
    PoseResult,
    PoseTrace,
    StageConfig,
    UpdateConfig,
    UpdateResult,
)

__all__ = [
    "UpdateFrame",
    "PoseOptimizer",
    "STATUSES",
    "AssociationConfig",
    "ChangeConfig",
    "InstanceUpdate",
    "NewMask",
    "NewInstance",
    "PoseConfig",
    "PoseProblem",
    "PoseResult",
    "PoseTrace",
    "StageConfig",
    "UpdateConfig",
    "UpdateResult",
]


@dataclass(frozen=True, eq=False)
class UpdateFrame:
    """One post-interaction frame to replay.

    Attributes:
        frame: frame index.
        rgb: (H, W, 3) uint8 image, or None.
        camera: its camera, or None.
        point_instance: (N,) int32 instance per point of the run's cloud after the update
            (-1 = removed / none), or None when only the image is known.
        text: a markdown summary of what changed.
        result: the full update (statuses, change masks, pose iterations), or None.
        instance0: (N,) int32 the chain's labelling before any update: the run's ids after the
            corrections the chain was computed from (``update.run_labels``); None = the run as
            segmented.
        added_now: the instances this update and the earlier ones added and did not remove, as
            the state saved after it holds them (moved by the updates since; the viewer builds
            the scene after it from them, ``update.scene_after.ChainInputs.added_points``).
        labels: the chain's ``state.json`` "labels" record (``run_labels.LabelSource``; None: not
            recorded, chains written before session 7), as ``scene_after.chain_inputs`` reads it.
        state_rows_sha256: ``run_labels.labels_sha256`` of the run rows of the state saved after this
            update (its labels less the added instances', in order), or None when unknown: what
            ``geometry.held_geometry`` checks (a chain written by an older version keeps its
            scene), so the viewer decides as ``clutt3r grasp --step`` without holding the rows.
        corrected_away: {id: why it is no instance} of the ids the corrections of ``instance0``
            merged, deleted or emptied (``run_labels.RunLabels.gone``; empty: none, or the run as segmented).
    """

    frame: int
    rgb: np.ndarray | None = None
    camera: Camera | None = None
    point_instance: np.ndarray | None = None
    text: str = ""
    result: UpdateResult | None = None
    instance0: np.ndarray | None = None
    added_now: tuple[NewInstance, ...] = ()
    labels: object | None = None
    state_rows_sha256: str | None = None
    corrected_away: Mapping[int, str] = field(default_factory=dict)


@runtime_checkable
class PoseOptimizer(Protocol):
    """Estimates the rigid motion of a displaced instance from one new image (Sec. III-C).

    ``optimize`` must be deterministic for a given problem and record every iteration in
    ``PoseResult.trace``.
    """

    name: str

    def optimize(self, problem: PoseProblem) -> PoseResult:
        """The instance's stored points, colours, the new view and its mask -> the motion."""
        ...
