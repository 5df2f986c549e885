"""Colour layers: the ordered list of ways to colour the point cloud.

A layer has a ``name`` (shown in the Scene tab's Colour list), ``available(inp)`` (whether
this run, in this tab, has what it needs) and ``colors(inp, state) -> (M, 3) uint8`` for
the displayed points ``inp.idx``; optionally ``colors_added(inp, state, instance, rgb)`` for the
points of instances an update added (not in the run's cloud; ``layer_added_colors``: instance
colours by default). The Colour list shows the available layers in
``COLOR_LAYERS`` order; the selected tree node is highlighted on top of any layer by the
session. Append a layer with ``register_color_layer``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from clutt3r_viewer.data import GREY, ViewerData, label_colors, ramp_colors
from clutt3r_viewer.state import SessionState

if TYPE_CHECKING:
    from clutt3r_viewer.events import EventSource

__all__ = ["HIGHLIGHT", "LayerInput", "ColorLayer", "COLOR_LAYERS", "register_color_layer", "layer_named",
           "available_layers", "InstanceLayer", "RgbLayer", "ConfidenceLayer", "ReplayLayer", "QueryLayer",
           "layer_added_colors", "ghost", "ghost_removed", "GHOST_WHITE"]

HIGHLIGHT = np.array([255, 215, 0], np.uint8)


@dataclass(frozen=True, eq=False)
class LayerInput:
    """What a colour layer reads (one tab's view of the run).

    Attributes:
        data: the run.
        idx: (M,) int64 indices of the displayed points (level of detail) into ``seg.points``.
        instance: (N,) int32 instance per point shown: the corrected labels when the run has edits.
        scores: (I,) float32 confidence per instance of ``instance``.
        replay: the Replay panel's current event source, or None.
    """

    data: ViewerData
    idx: np.ndarray
    instance: np.ndarray
    scores: np.ndarray
    replay: "EventSource | None" = None


@runtime_checkable
class ColorLayer(Protocol):
    name: str

    def available(self, inp: LayerInput, state: SessionState) -> bool: ...

    def colors(self, inp: LayerInput, state: SessionState) -> np.ndarray:
        """(len(inp.idx), 3) uint8."""
        ...


GHOST_WHITE = 0.75
"""Removed instances' points are drawn as their instance colour blended this much with white."""


def ghost(col: np.ndarray, gone: np.ndarray, instance0: np.ndarray) -> np.ndarray:
    """``col`` (M, 3) with the points ``gone`` (M,) bool drawn pale in the colour of the instance
    ``instance0`` (M,) they belonged to (``GHOST_WHITE``; the chain's ids,
    ``ShownScene.last_instance``): removed instances, where they were last seen."""
    if not gone.any():
        return col
    col = col.copy()
    own = label_colors(np.asarray(instance0)[gone]).astype(np.float32)
    col[gone] = np.round((1 - GHOST_WHITE) * own + GHOST_WHITE * 255).astype(np.uint8)
    return col


def ghost_removed(col: np.ndarray, scene) -> np.ndarray:
    """``ghost`` for the points of instances removed by the scene shown (a ``ShownScene``), in
    the colours of the ids the chain removed (the corrected ids when the chain has corrections)."""
    return ghost(col, scene.gone, scene.last_instance)


def layer_added_colors(layer: "ColorLayer", inp: LayerInput, state: SessionState, instance: np.ndarray,
                       rgb: np.ndarray) -> np.ndarray:
    """(A, 3) uint8 colours of added instances' points (ids ``instance``, own colours ``rgb``) in
    ``layer``: its ``colors_added`` when it has one, else the instance colours."""
    fn = getattr(layer, "colors_added", None)
    return fn(inp, state, instance, rgb) if fn is not None else label_colors(instance)


@dataclass(frozen=True)
class InstanceLayer:
    name: str = "instance"

    def available(self, inp: LayerInput, state: SessionState) -> bool:
        return True

    def colors(self, inp: LayerInput, state: SessionState) -> np.ndarray:
        return label_colors(inp.instance[inp.idx])


@dataclass(frozen=True)
class RgbLayer:
    name: str = "rgb"

    def available(self, inp: LayerInput, state: SessionState) -> bool:
        return True

    def colors(self, inp: LayerInput, state: SessionState) -> np.ndarray:
        return inp.data.seg.colors[inp.idx].copy()

    def colors_added(self, inp: LayerInput, state: SessionState, instance: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        return np.asarray(rgb, np.uint8).copy()


@dataclass(frozen=True)
class ConfidenceLayer:
    """Instance confidence on a ramp from 0 to the highest score; grey = no instance."""

    name: str = "confidence"

    def available(self, inp: LayerInput, state: SessionState) -> bool:
        return True

    def colors(self, inp: LayerInput, state: SessionState) -> np.ndarray:
        inst = inp.instance[inp.idx]
        col = np.tile(GREY, (len(inst), 1))
        has = inst >= 0
        hi = float(inp.scores.max()) if len(inp.scores) else 1.0
        col[has] = ramp_colors(inp.scores[inst[has]], 0.0, hi)
        return col

    def colors_added(self, inp: LayerInput, state: SessionState, instance: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        return np.tile(GREY, (len(instance), 1))  # an added instance has no grouping confidence


@dataclass(frozen=True)
class ReplayLayer:
    """The Replay panel's event source at the tab's current event."""

    name: str = "replay"

    def available(self, inp: LayerInput, state: SessionState) -> bool:
        return inp.replay is not None

    def colors(self, inp: LayerInput, state: SessionState) -> np.ndarray:
        assert inp.replay is not None
        return inp.replay.colors(state.event, inp.idx)


@dataclass(frozen=True)
class QueryLayer:
    """Text-query score per instance on a ramp; the best instance in the highlight colour."""

    name: str = "query"

    def available(self, inp: LayerInput, state: SessionState) -> bool:
        # one score per instance id of the chain (added ids after the run's); NaN = not ranked
        return state.query_scores is not None and len(state.query_scores) >= len(inp.scores)

    def colors(self, inp: LayerInput, state: SessionState) -> np.ndarray:
        return self._colors(inp.instance[inp.idx], state)

    def colors_added(self, inp: LayerInput, state: SessionState, instance: np.ndarray, rgb: np.ndarray) -> np.ndarray:
        return self._colors(np.asarray(instance), state)

    @staticmethod
    def _colors(inst: np.ndarray, state: SessionState) -> np.ndarray:
        sc = state.query_scores
        assert sc is not None
        col = np.tile(GREY, (len(inst), 1))
        has = (inst >= 0) & (inst < len(sc))
        fin = sc[np.isfinite(sc)]
        if len(fin):
            col[has] = ramp_colors(sc[inst[has]], float(fin.min()), float(fin.max()))
        col[inst == state.query_best] = HIGHLIGHT
        return col


# The "update" layer (the scene after a post-interaction frame) is registered by
# panels.update_sources, which owns the update chain's data.
COLOR_LAYERS: list[ColorLayer] = [InstanceLayer(), RgbLayer(), ConfidenceLayer(), ReplayLayer(), QueryLayer()]


def register_color_layer(layer: ColorLayer) -> ColorLayer:
    """Append a layer (names are unique: a layer with the same name is replaced in place)."""
    for k, old in enumerate(COLOR_LAYERS):
        if old.name == layer.name:
            COLOR_LAYERS[k] = layer
            return layer
    COLOR_LAYERS.append(layer)
    return layer


def available_layers(inp: LayerInput, state: SessionState) -> list[ColorLayer]:
    return [layer for layer in COLOR_LAYERS if layer.available(inp, state)]


def layer_named(name: str) -> ColorLayer | None:
    return next((layer for layer in COLOR_LAYERS if layer.name == name), None)
