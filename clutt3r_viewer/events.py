"""Ordered event sources the Replay panel steps through.

An ``EventSource`` is anything with a number of steps, a text per step and the colours
(and, optionally, positions) of the displayed points after each step. Step 0 is the
state before the first event; step ``num_events`` is the final state. Two implementations:

- ``GroupingEvents``: the grouping's merges and substitutions (``Trace.grouping.events``),
  each point coloured by the super-voxel vote of the groups at that step.
- ``PoseIterations``: iterations of a per-object pose optimisation; step n moves every
  object's points by its pose at iteration n (``T_world_object`` relative to the start)
  and colours them by that object's residual.

New sources are added with ``register_event_source(factory)``; ``factory(data)`` returns a
source or None when the run has no such events (the Replay panel then does not list it).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable, Protocol, runtime_checkable

import numpy as np

from clutt3r_viewer.data import event_text, label_colors, ramp_colors

if TYPE_CHECKING:
    from clutt3r_viewer.data import ViewerData

__all__ = ["EventSource", "GroupingEvents", "PoseIterations", "EVENT_SOURCES", "register_event_source",
           "event_sources"]


@runtime_checkable
class EventSource(Protocol):
    """An ordered sequence of steps over the run's points (module docstring)."""

    name: str  # shown in the Replay panel's source list; unique among the sources of a run

    @property
    def num_events(self) -> int: ...

    def text(self, n: int) -> str:
        """Markdown describing step n (0 = before the first event)."""
        ...

    def colors(self, n: int, idx: np.ndarray) -> np.ndarray:
        """(len(idx), 3) uint8 colours of points ``idx`` (indices into ``seg.points``) after n events."""
        ...

    def points(self, n: int, idx: np.ndarray) -> np.ndarray | None:
        """(len(idx), 3) float32 world positions (metres) of points ``idx`` after n events, or None
        when this source never moves points (the cloud keeps its positions)."""
        ...


@dataclass(frozen=True, eq=False)
class GroupingEvents:
    """The grouping's events (Sec. III-B): merge after merge, then substitutions."""

    data: "ViewerData"
    name: str = "grouping"

    @property
    def num_events(self) -> int:
        return self.data.num_events

    def text(self, n: int) -> str:
        d = self.data
        return (f"{event_text(d.trace, n)}  \n{d.replay_num_groups(n)} groups so far; colour = super-voxel vote "
                f"of those groups (final: {d.seg.num_instances} instances)")

    def colors(self, n: int, idx: np.ndarray) -> np.ndarray:
        return label_colors(self.data.replay_sv_group(n)[self.data.seg.sv_labels[idx]])

    def points(self, n: int, idx: np.ndarray) -> np.ndarray | None:
        return None


@dataclass(frozen=True, eq=False)
class PoseIterations:
    """Iterations of a per-object pose optimisation (e.g. after an interaction).

    Attributes:
        instance: (N,) int instance of every point (-1 = static, never moved).
        poses: (T, I, 4, 4) float64 ``T_world_object`` motion of instance i at iteration t,
            applied to the points as they are in the run (identity = not moved).
        residual: (T, I) float64 per-object residual at iteration t (any unit; coloured on
            a ramp from the smallest to the largest value of the whole optimisation).
        points0: (N, 3) float32 the run's point positions, metres.
        name: shown in the source list.
        context_rgb: optional (N, 3) uint8 colours of the points; static points (instance -1)
            are drawn in them, dimmed, so the moving object stays readable against its
            neighbours (None: static points grey, like the table).
    """

    instance: np.ndarray
    poses: np.ndarray
    residual: np.ndarray
    points0: np.ndarray
    name: str = "pose optimisation"
    context_rgb: np.ndarray | None = None
    _lo_hi: tuple[float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        t, i = self.residual.shape
        if self.poses.shape != (t, i, 4, 4):
            raise ValueError(f"poses {self.poses.shape} != (T, I, 4, 4) = ({t}, {i}, 4, 4)")
        if self.instance.shape != (len(self.points0),) or int(self.instance.max(initial=-1)) >= i:
            raise ValueError("instance must be (N,) with ids < I")
        if self.context_rgb is not None and self.context_rgb.shape != (len(self.points0), 3):
            raise ValueError(f"context_rgb {self.context_rgb.shape} != (N, 3) = ({len(self.points0)}, 3)")
        fin = self.residual[np.isfinite(self.residual)]
        object.__setattr__(self, "_lo_hi", (float(fin.min()), float(fin.max())) if len(fin) else (0.0, 1.0))

    @property
    def num_events(self) -> int:
        return len(self.residual) - 1  # step 0 = iteration 0 (the start)

    def _it(self, n: int) -> int:
        return int(np.clip(n, 0, self.num_events))

    def text(self, n: int) -> str:
        t = self._it(n)
        r = self.residual[t]
        # iteration 0 has no residual yet (all NaN): no mean to show
        return f"**iteration {t}/{self.num_events}**: mean residual {float(np.nanmean(r)):.4g}" \
            if np.isfinite(r).any() else f"**iteration {t}/{self.num_events}**"

    def colors(self, n: int, idx: np.ndarray) -> np.ndarray:
        inst = self.instance[idx]
        r = np.full(len(idx), np.nan)
        has = inst >= 0
        r[has] = self.residual[self._it(n)][inst[has]]
        out = ramp_colors(r, *self._lo_hi)
        if self.context_rgb is not None:
            # dimmed to 55 % so the ramp-coloured moving points stay the brightest thing
            out[~has] = (self.context_rgb[idx[~has]].astype(np.float32) * 0.55).astype(np.uint8)
        return out

    def points(self, n: int, idx: np.ndarray) -> np.ndarray | None:
        p = self.points0[idx].astype(np.float64)
        inst = self.instance[idx]
        T = self.poses[self._it(n)]
        has = inst >= 0
        R, t = T[inst[has], :3, :3], T[inst[has], :3, 3]
        p[has] = np.einsum("nij,nj->ni", R, p[has]) + t
        return p.astype(np.float32)


EventSourceFactory = Callable[["ViewerData"], "EventSource | None"]
EVENT_SOURCES: list[EventSourceFactory] = [GroupingEvents]
"""Factories, in the order the Replay panel lists their sources (the first is the default)."""


def register_event_source(factory: EventSourceFactory) -> EventSourceFactory:
    """Add a source of events: ``factory(data)`` returns an ``EventSource`` or None."""
    EVENT_SOURCES.append(factory)
    return factory


def event_sources(data: "ViewerData") -> list[EventSource]:
    """The sources this run has, in registration order."""
    out = [f(data) for f in EVENT_SOURCES]
    return [s for s in out if s is not None]
