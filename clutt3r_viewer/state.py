"""What one browser tab has selected, and the kinds of change panels react to.

Kept apart from ``app.py`` so that colour layers, event sources and panels can name
these types without importing viser.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

__all__ = ["SessionState", "Change"]


class Change(enum.Flag):
    """What changed, broadcast by ``Session.changed`` to every panel's ``refresh``.

    A flag (not a string key) so that a panel tests ``if change & Change.NODE`` and a typo
    is an AttributeError, not a silently ignored event.
    """

    NONE = 0
    VIEW = enum.auto()     # state.view (the node selection is cleared with it)
    NODE = enum.auto()     # state.node
    LABELS = enum.auto()   # the run's corrected labels (an edit in any tab)
    COLOUR = enum.auto()   # colour layer or its input (event, query, update frame)
    LOD = enum.auto()      # the displayed point subset
    SCENE = enum.auto()    # the scene shown (state.update / update_after: the updates applied)
    INSTANCE = enum.auto()  # state.instance (the selected instance)


@dataclass
class SessionState:
    """What one browser tab has selected (server side; tests assert on it)."""

    view: int = 0
    node: int = -1
    color_mode: str = "instance"
    event: int = 0
    replay_source: str = "grouping"
    edge_weight: str = "spatial"
    edge_threshold: float = 0.5
    show_edges: bool = False
    lod: str = "200k"
    query: str = ""
    query_best: int = -1
    query_scores: np.ndarray | None = None  # (I,) float32 text score per instance of the last query
    grasp: int = -1
    update: int = -1
    update_after: bool = True  # the Updates tab shows the scene after (else before) its update
    instance: int = -1  # the selected instance (highlighted in every colour mode; the Grasps tab's target)
    playing: bool = False
    edit_instance: int = -1
