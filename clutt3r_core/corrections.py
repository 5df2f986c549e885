"""Correction operations on a run's instance labelling and their pure semantics (replay).

The operations (``Relabel``, ``Merge``, ``Split``, ``SetCategory``, ``Delete``, ``Undo``,
``Redo``), their JSON form, the labels they act on (``BaseLabels`` -> ``CorrectedLabels``) and
``apply``, which replays a log's entries. The durable, append-only log on disk that records
them is ``clutt3r_core.annotations`` (split from it along this seam: the model here has no
I/O, the log there has all of it). Semantics of undo / redo and of ids: see that module.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, fields
from functools import cached_property
from typing import Union

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = [
    "Relabel",
    "Merge",
    "Split",
    "SetCategory",
    "Delete",
    "Undo",
    "Redo",
    "Op",
    "EditOp",
    "BaseLabels",
    "CorrectedLabels",
    "active_edits",
    "apply",
    "op_to_json",
    "op_from_json",
    "selection_fields",
    "category_suggestions",
]


def _int_tuple(values, what: str) -> tuple[int, ...]:
    if isinstance(values, dict):  # the compact JSON form of a long selection (see op_to_json)
        values = _expand_ranges(values.get("ranges", ()), what)
    a = np.asarray(values, dtype=np.int64).reshape(-1)
    if a.size and a.min() < 0:
        raise SceneError(f"{what}: indices must be >= 0")
    return tuple(a.tolist())  # tolist: ~20x faster than a generator for 100k-point selections


def _ranges(values: tuple[int, ...]) -> list[int] | None:
    """[start0, stop0, start1, stop1, ...] of the sorted unique ``values`` (half-open runs), or None
    when that is not shorter than the list itself (scattered points)."""
    if len(values) < 8:
        return None
    a = np.unique(np.asarray(values, np.int64))
    if len(a) != len(values):
        return None  # duplicates: keep the literal list so the op round-trips exactly
    if not np.array_equal(a, np.asarray(values, np.int64)):
        return None  # unsorted: same reason
    brk = np.flatnonzero(np.diff(a) != 1) + 1
    starts = np.concatenate([a[:1], a[brk]])
    stops = np.concatenate([a[brk - 1] + 1, a[-1:] + 1])
    if 2 * len(starts) >= len(a):
        return None
    return np.stack([starts, stops], 1).reshape(-1).tolist()


def _expand_ranges(r, what: str) -> np.ndarray:
    r = np.asarray(r, np.int64).reshape(-1)
    if len(r) % 2 or (len(r) and ((r[1::2] < r[0::2]).any() or r.min() < 0)):
        raise SceneError(f"{what}: bad ranges (want [start, stop, ...] with stop >= start >= 0)")
    if not len(r):
        return r
    return np.concatenate([np.arange(a, b) for a, b in zip(r[0::2], r[1::2])])


def _now() -> float:
    return time.time()


# -- operations ------------------------------------------------------------------------


@dataclass(frozen=True)
class Relabel:
    """Give the points of ``supervoxels`` and the listed ``points`` the instance ``target`` (-1 = none).

    Attributes:
        target: existing, not deleted instance id, or -1.
        supervoxels: super-voxel ids (``Segmentation.sv_labels`` values).
        points: point indices into the run's cloud.
    """

    target: int
    supervoxels: tuple[int, ...] = ()
    points: tuple[int, ...] = ()
    author: str = ""
    time: float = field(default_factory=_now)

    def __post_init__(self) -> None:
        object.__setattr__(self, "supervoxels", _int_tuple(self.supervoxels, "Relabel.supervoxels"))
        object.__setattr__(self, "points", _int_tuple(self.points, "Relabel.points"))
        if int(self.target) < -1:
            raise SceneError("Relabel.target must be an instance id or -1")


@dataclass(frozen=True)
class Merge:
    """Instance ``other`` (and every id in ``others``) joins instance ``into``; the merged ids are
    deleted (never reused). ``others`` lets one entry (one undo) merge a whole selection."""

    into: int
    other: int
    author: str = ""
    time: float = field(default_factory=_now)
    others: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "others", _int_tuple(self.others, "Merge.others"))
        ids = (int(self.other),) + self.others
        if int(self.into) in ids:
            raise SceneError(f"Merge: an instance cannot merge into itself (I{self.into})")
        if len(set(ids)) != len(ids):
            raise SceneError(f"Merge: an instance is listed twice ({list(ids)})")

    @property
    def merged(self) -> tuple[int, ...]:
        """Every id that joins ``into``."""
        return (int(self.other),) + self.others


@dataclass(frozen=True)
class Split:
    """Move the points of ``supervoxels`` / ``points`` to a new instance (id = current count).

    Attributes:
        source: when set, only points currently in this instance move (splitting it);
            None moves every listed point, whatever its instance.
        score: confidence of the new instance (ours: 1.0, a person made it).
    """

    supervoxels: tuple[int, ...] = ()
    points: tuple[int, ...] = ()
    source: int | None = None
    score: float = 1.0
    author: str = ""
    time: float = field(default_factory=_now)

    def __post_init__(self) -> None:
        object.__setattr__(self, "supervoxels", _int_tuple(self.supervoxels, "Split.supervoxels"))
        object.__setattr__(self, "points", _int_tuple(self.points, "Split.points"))


@dataclass(frozen=True)
class SetCategory:
    """Set the category / name text of an instance."""

    instance: int
    text: str
    author: str = ""
    time: float = field(default_factory=_now)


@dataclass(frozen=True)
class Delete:
    """Delete an instance: its points become -1 and its id is marked deleted."""

    instance: int
    author: str = ""
    time: float = field(default_factory=_now)


@dataclass(frozen=True)
class Undo:
    """Revert the edit at log index ``target`` (must be the most recent active edit)."""

    target: int
    author: str = ""
    time: float = field(default_factory=_now)


@dataclass(frozen=True)
class Redo:
    """Re-apply the edit at log index ``target`` (must be the most recently undone edit)."""

    target: int
    author: str = ""
    time: float = field(default_factory=_now)


EditOp = Union[Relabel, Merge, Split, SetCategory, Delete]
Op = Union[Relabel, Merge, Split, SetCategory, Delete, Undo, Redo]
_KINDS: dict[str, type] = {
    "relabel": Relabel, "merge": Merge, "split": Split, "set_category": SetCategory,
    "delete": Delete, "undo": Undo, "redo": Redo,
}
_KIND_OF = {cls: k for k, cls in _KINDS.items()}


def op_to_json(op: Op) -> dict:
    """The JSON object of one log line (``{"op": kind, ...fields}``)."""
    d: dict = {"op": _KIND_OF[type(op)]}
    for f in fields(op):
        v = getattr(op, f.name)
        if isinstance(v, tuple):
            if f.name == "others" and not v:
                continue  # older readers know Merge without it
            r = _ranges(v)
            # a box selection is mostly runs of consecutive indices (points are stored in
            # super-voxel order): [start, stop, ...] keeps a 100k-point selection to a few KB
            v = {"ranges": r} if r is not None else list(v)
        d[f.name] = v
    return d


def op_from_json(d: dict) -> Op:
    """Inverse of ``op_to_json``; raises SceneError on an unknown kind or bad fields."""
    if not isinstance(d, dict) or d.get("op") not in _KINDS:
        raise SceneError(f"unknown operation {d.get('op') if isinstance(d, dict) else d!r}")
    cls = _KINDS[d["op"]]
    names = {f.name for f in fields(cls)}
    kw = {k: v for k, v in d.items() if k in names}
    try:
        return cls(**kw)
    except TypeError as e:
        raise SceneError(f"bad {d['op']} operation: {e}") from None


# -- labels ----------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class BaseLabels:
    """The uncorrected labelling the log applies to (what ``apply`` reads from a Segmentation).

    Attributes:
        instance: (N,) int32 instance per point, -1 = none.
        scores: (K,) float32 instance confidences.
        sv_labels: (N,) int32 super-voxel of each point.
    """

    instance: np.ndarray
    scores: np.ndarray
    sv_labels: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "instance", np.asarray(self.instance, np.int32))
        object.__setattr__(self, "scores", np.asarray(self.scores, np.float32))
        object.__setattr__(self, "sv_labels", np.asarray(self.sv_labels, np.int32))
        n, k = len(self.instance), len(self.scores)
        if self.instance.shape != (n,) or self.sv_labels.shape != (n,):
            raise SceneError("BaseLabels: instance (N,) and sv_labels (N,) must agree")
        if n and (self.instance.min() < -1 or self.instance.max() >= k):
            raise SceneError(f"BaseLabels: instance ids must lie in -1..{k - 1}")

    @staticmethod
    def of(seg) -> "BaseLabels":
        """From a ``Segmentation`` (or anything with instance, scores, sv_labels)."""
        if isinstance(seg, BaseLabels):
            return seg
        return BaseLabels(seg.instance, seg.scores, seg.sv_labels)

    @property
    def num_supervoxels(self) -> int:
        return int(self.sv_labels.max()) + 1 if len(self.sv_labels) else 0

    @cached_property
    def _sv_index(self) -> tuple[np.ndarray, np.ndarray]:
        """(order, starts): points of super-voxel s are order[starts[s]:starts[s + 1]] (built once)."""
        order = np.argsort(self.sv_labels, kind="stable")
        starts = np.searchsorted(self.sv_labels[order], np.arange(self.num_supervoxels + 1))
        return order, starts

    def selection_indices(self, supervoxels, points, what: str = "selection") -> np.ndarray:
        """(M,) int64 sorted unique point indices named by ``supervoxels`` and ``points``: the
        same set as the edit's boolean selection, in O(M log M) instead of O(N); same errors."""
        parts = []
        if len(supervoxels):
            sv = np.asarray(supervoxels, np.int64)
            ks = self.num_supervoxels
            if sv.max() >= ks:
                raise SceneError(f"{what}: super-voxel {int(sv.max())} does not exist (0..{ks - 1})")
            order, starts = self._sv_index
            parts += [order[starts[k]:starts[k + 1]] for k in np.unique(sv)]
        if len(points):
            p = np.asarray(points, np.int64)
            n = len(self.instance)
            if p.max() >= n:
                raise SceneError(f"{what}: point {int(p.max())} does not exist (0..{n - 1})")
            parts.append(p)
        return np.unique(np.concatenate(parts)) if parts else np.zeros(0, np.int64)


@dataclass(frozen=True, eq=False)
class CorrectedLabels:
    """The labelling after the active edits of a log.

    Attributes:
        instance: (N,) int32 instance per point, -1 = none; ids index ``scores``.
        scores: (K,) float32 confidence per instance id (new instances: the Split's score).
        categories: K category / name texts ("" = not set).
        deleted: (K,) bool ids removed by Merge / Delete (they have no points).
    """

    instance: np.ndarray
    scores: np.ndarray
    categories: tuple[str, ...]
    deleted: np.ndarray

    def __post_init__(self) -> None:
        k = len(self.scores)
        if self.instance.ndim != 1 or len(self.categories) != k or self.deleted.shape != (k,):
            raise SceneError("CorrectedLabels: instance (N,), scores (K,), categories (K), deleted (K,) must agree")
        if len(self.instance) and (self.instance.min() < -1 or self.instance.max() >= k):
            raise SceneError(f"CorrectedLabels: instance ids must lie in -1..{k - 1}")

    @property
    def num_instances(self) -> int:
        """Number of ids (deleted ones included)."""
        return len(self.scores)

    @property
    def alive(self) -> np.ndarray:
        """(K,) int64 ids that are not deleted."""
        return np.flatnonzero(~self.deleted)

    def point_counts(self) -> np.ndarray:
        """(K,) int64 points per id."""
        return np.bincount(self.instance[self.instance >= 0], minlength=self.num_instances)

    def compact(self) -> tuple[np.ndarray, np.ndarray, tuple[str, ...]]:
        """(instance (N,) int32, scores (K',) float32, categories) with deleted and empty ids
        dropped and the rest renumbered 0..K'-1 in id order (for export / evaluation)."""
        keep = ~self.deleted & (self.point_counts() > 0)
        new = np.full(self.num_instances + 1, -1, np.int32)  # last slot maps -1 to -1
        new[np.flatnonzero(keep)] = np.arange(int(keep.sum()), dtype=np.int32)
        return new[self.instance], self.scores[keep].copy(), tuple(c for c, k in zip(self.categories, keep) if k)

    def equals(self, other: "CorrectedLabels") -> bool:
        return (np.array_equal(self.instance, other.instance) and np.array_equal(self.scores, other.scores)
                and self.categories == other.categories and np.array_equal(self.deleted, other.deleted))


def _initial(base: BaseLabels) -> CorrectedLabels:
    k = len(base.scores)
    return CorrectedLabels(base.instance.copy(), base.scores.copy(), ("",) * k, np.zeros(k, bool))


def active_edits(ops) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(active, redoable): log indices of the edits in effect (oldest first) and the redo stack
    (bottom first) after the entries ``ops``. Raises SceneError naming the entry on an Undo / Redo
    that does not match the stacks (a log no editor could have written)."""
    active: list[int] = []
    redo: list[int] = []
    for i, op in enumerate(ops):
        if isinstance(op, Undo):
            if not active or active[-1] != op.target:
                raise SceneError(f"entry {i}: Undo({op.target}) but the last active edit is "
                                 f"{active[-1] if active else 'none'}")
            redo.append(active.pop())
        elif isinstance(op, Redo):
            if not redo or redo[-1] != op.target:
                raise SceneError(f"entry {i}: Redo({op.target}) but the last undone edit is "
                                 f"{redo[-1] if redo else 'none'}")
            active.append(redo.pop())
        else:
            active.append(i)
            redo.clear()
    return tuple(active), tuple(redo)


def _check_id(lab: CorrectedLabels, k: int, what: str, allow_none: bool = False) -> None:
    if allow_none and k == -1:
        return
    if not 0 <= k < lab.num_instances:
        raise SceneError(f"{what}: instance I{k} does not exist (ids 0..{lab.num_instances - 1})")
    if lab.deleted[k]:
        raise SceneError(f"{what}: instance I{k} was deleted")


def _selection(base: BaseLabels, supervoxels: tuple[int, ...], points: tuple[int, ...], what: str) -> np.ndarray:
    n = len(base.instance)
    sel = np.zeros(n, bool)
    if supervoxels:
        sv = np.asarray(supervoxels, np.int64)
        ks = base.num_supervoxels
        if sv.max() >= ks:
            raise SceneError(f"{what}: super-voxel {int(sv.max())} does not exist (0..{ks - 1})")
        lut = np.zeros(ks, bool)
        lut[sv] = True
        sel |= lut[base.sv_labels]
    if points:
        p = np.asarray(points, np.int64)
        if p.max() >= n:
            raise SceneError(f"{what}: point {int(p.max())} does not exist (0..{n - 1})")
        sel[p] = True
    return sel


def _apply_edit(base: BaseLabels, lab: CorrectedLabels, op: EditOp) -> CorrectedLabels:
    """One edit on ``lab`` (new arrays; ``lab`` is not modified). Raises SceneError if invalid."""
    inst, scores, cats, deleted = lab.instance, lab.scores, list(lab.categories), lab.deleted
    name = type(op).__name__
    if isinstance(op, Relabel):
        _check_id(lab, int(op.target), name, allow_none=True)
        inst = np.where(_selection(base, op.supervoxels, op.points, name), np.int32(op.target), inst)
    elif isinstance(op, Merge):
        _check_id(lab, int(op.into), name)
        for o in op.merged:
            _check_id(lab, o, name)
        lut = np.arange(-1, lab.num_instances, dtype=np.int32)  # lut[k + 1] = new id of k
        lut[np.asarray(op.merged) + 1] = np.int32(op.into)
        inst = lut[inst + 1]
        deleted = deleted.copy()
        deleted[list(op.merged)] = True
    elif isinstance(op, Split):
        if op.source is not None:
            _check_id(lab, int(op.source), name, allow_none=True)
        sel = _selection(base, op.supervoxels, op.points, name)
        if op.source is not None:
            sel &= inst == op.source
        if not sel.any():
            raise SceneError(f"{name}: no point to move")
        k = lab.num_instances
        inst = np.where(sel, np.int32(k), inst)
        scores = np.append(scores, np.float32(op.score)).astype(np.float32)
        cats.append("")
        deleted = np.append(deleted, False)
    elif isinstance(op, SetCategory):
        _check_id(lab, int(op.instance), name)
        cats[op.instance] = str(op.text)
    elif isinstance(op, Delete):
        _check_id(lab, int(op.instance), name)
        inst = np.where(inst == op.instance, np.int32(-1), inst)
        deleted = deleted.copy()
        deleted[op.instance] = True
    else:
        raise SceneError(f"not an edit operation: {op!r}")
    return CorrectedLabels(inst.astype(np.int32, copy=False), scores, tuple(cats), deleted)


def apply(segmentation, ops) -> CorrectedLabels:
    """The corrected labelling after the log entries ``ops`` (edits, undos, redos) on ``segmentation``
    (a ``Segmentation`` or ``BaseLabels``). Pure: replays the active edits in order, each one a
    vectorised array operation. Raises SceneError on an invalid entry."""
    base = BaseLabels.of(segmentation)
    ops = tuple(ops)
    active, _ = active_edits(ops)
    lab = _initial(base)
    for i in active:
        try:
            lab = _apply_edit(base, lab, ops[i])
        except SceneError as e:
            raise SceneError(f"entry {i}: {e}") from None
    return lab


# -- selections ------------------------------------------------------------------------


def selection_fields(base: BaseLabels, mask: np.ndarray) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """(supervoxels, points) naming exactly the points of the (N,) bool ``mask``: every super-voxel
    the mask covers whole goes in by id (a click selection is a few ids), the rest as points (a box
    selection cutting super-voxels; encoded as runs in the log, see ``op_to_json``)."""
    mask = np.asarray(mask, bool)
    if mask.shape != base.instance.shape:
        raise SceneError(f"selection: mask of {mask.shape} for {len(base.instance)} points")
    ks = base.num_supervoxels
    total = np.bincount(base.sv_labels, minlength=ks)
    picked = np.bincount(base.sv_labels[mask], minlength=ks)
    whole = (picked == total) & (total > 0)
    rest = mask & ~whole[base.sv_labels]
    return tuple(np.flatnonzero(whole).tolist()), tuple(np.flatnonzero(rest).tolist())


def category_suggestions(labels: CorrectedLabels, prefix: str = "", extra: tuple[str, ...] = ()) -> tuple[str, ...]:
    """Category texts already used on live instances (most used first), then ``extra`` (e.g. the
    run's query vocabulary), filtered by case-insensitive ``prefix``; no duplicates."""
    counts: dict[str, int] = {}
    for k in labels.alive:
        c = labels.categories[k]
        if c:
            counts[c] = counts.get(c, 0) + 1
    out = sorted(counts, key=lambda c: (-counts[c], c)) + [e for e in extra if e and e not in counts]
    p = prefix.strip().lower()
    seen: set[str] = set()
    res = []
    for c in out:
        if c.lower().startswith(p) and c not in seen:
            seen.add(c)
            res.append(c)
    return tuple(res)
