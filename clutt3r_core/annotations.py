"""User corrections of a run's instance labelling: an append-only operation log with undo / redo.

The original ``instances.npz`` of a run is never modified. Corrections live beside it:

    corrections/ops.jsonl                 header line + one JSON line per operation (append-only)
    corrections/instances_corrected.npz   snapshot of the corrected labelling (a cache of the log)
    corrections/ops.jsonl.torn            bytes of a torn last line cut off on recovery (kept, never read)

Durability (why each step is there):
- An operation counts as done only after its line is written and ``fsync``-ed; a crash loses
  at most the operation being written. The log header is created with link(2) from a fsynced
  temp file, so it is complete or absent, and two writers cannot both create it.
- A torn / unparsable **last** line (crash mid-append) is reported with a ``CorrectionLogWarning``
  naming the file and line and ignored; a writer moves its bytes to ``ops.jsonl.torn`` and
  truncates the log to its last complete line before appending. A bad line **before** the last
  is an error (``SceneFileError`` naming file and line): earlier operations are never guessed.
- The snapshot is written with ``atomic_write_bytes`` (temp + fsync + rename): the old or the new
  file, never a partial one. It records how many log entries it reflects and a SHA-256 of those
  log bytes; ``Annotations.open`` uses it only when it matches the log exactly, else replays.
- The header stores the SHA-256 of ``instances.npz``: a log copied next to another run is rejected.
- A writer holds an exclusive ``flock`` on the log for its lifetime (released by the kernel
  when the process dies), so two processes never interleave appends.

Undo and redo are log entries themselves (``Undo(target)`` / ``Redo(target)``, ``target`` the
log index of the edit they revert / re-apply), so the log stays append-only and replaying
it from the start gives the current state. Semantics are an editor's: the active edits form a
stack; ``Undo`` pops its top onto the redo stack, ``Redo`` pushes the redo stack's top back,
and any new edit clears the redo stack.

Instance ids are stable while editing: ``Split`` appends a new id ``K`` (the number of
instances so far, deleted ones included); ``Merge`` and ``Delete`` mark ids deleted without
renumbering (``CorrectedLabels.compact`` renumbers for export). Conventions: docs/conventions.md
(ids 0-based, -1 = none).
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
import warnings
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Union

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import atomic_write_bytes, npz_bytes

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
    "LogEntry",
    "CorrectionLogWarning",
    "CorrectionLogLocked",
    "active_edits",
    "apply",
    "op_to_json",
    "op_from_json",
    "Annotations",
    "LOG_NAME",
    "SNAPSHOT_NAME",
]

LOG_NAME = "corrections/ops.jsonl"
SNAPSHOT_NAME = "corrections/instances_corrected.npz"
_FORMAT = "clutt3r-corrections"
_VERSION = 1


class CorrectionLogWarning(UserWarning):
    """A torn last line of a correction log was found and ignored (the message names file and line)."""


class CorrectionLogLocked(SceneFileError):
    """Another live process holds the correction log of this run for writing."""


def _int_tuple(values, what: str) -> tuple[int, ...]:
    a = np.asarray(values, dtype=np.int64).reshape(-1)
    if a.size and a.min() < 0:
        raise SceneError(f"{what}: indices must be >= 0")
    return tuple(int(x) for x in a)


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
    """Instance ``other`` joins instance ``into``; ``other`` is deleted (its id is not reused)."""

    into: int
    other: int
    author: str = ""
    time: float = field(default_factory=_now)

    def __post_init__(self) -> None:
        if self.into == self.other:
            raise SceneError(f"Merge: an instance cannot merge into itself (I{self.into})")


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
        d[f.name] = list(v) if isinstance(v, tuple) else v
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
        _check_id(lab, int(op.other), name)
        inst = np.where(inst == op.other, np.int32(op.into), inst)
        deleted = deleted.copy()
        deleted[op.other] = True
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


# -- the log on disk -------------------------------------------------------------------


@dataclass(frozen=True)
class LogEntry:
    """One entry of ``Annotations.history()``: its log index, the operation, whether it is in effect
    (an edit on the active stack; Undo / Redo entries are never 'active')."""

    index: int
    op: Op
    active: bool


def _file_sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


@dataclass(frozen=True)
class _ParsedLog:
    header: dict
    ops: tuple
    good_bytes: int  # bytes up to and including the last complete entry's newline
    ends: tuple[int, ...]  # byte offset after entry i's newline
    torn_line: int  # 1-based line number of the ignored torn line, 0 if none


def _parse_log(path: Path) -> _ParsedLog:
    data = path.read_bytes()
    lines = data.split(b"\n")
    # a file ending in "\n" splits into [..., b""]: the last element is the unterminated tail
    tail = lines.pop()
    complete = lines
    if not complete:
        raise SceneFileError(path, "line 1: missing or torn header (not a correction log)")
    try:
        header = json.loads(complete[0])
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SceneFileError(path, f"line 1: header is not JSON: {e}") from None
    if not isinstance(header, dict) or header.get("format") != _FORMAT:
        raise SceneFileError(path, f"line 1: not a correction log header (format != {_FORMAT!r})")
    if header.get("version") != _VERSION:
        raise SceneFileError(path, f"line 1: unsupported correction log version {header.get('version')!r}")
    ops, ends = [], []
    pos = len(complete[0]) + 1
    torn_line = 0
    for ln, raw in enumerate(complete[1:], start=2):
        last = ln == len(complete) and not tail
        try:
            d = json.loads(raw)
            if not isinstance(d, dict) or d.get("seq") != len(ops):
                raise SceneError(f"entry number {d.get('seq') if isinstance(d, dict) else '?'} "
                                 f"where {len(ops)} was expected")
            op = op_from_json(d)
        except (json.JSONDecodeError, UnicodeDecodeError, SceneError) as e:
            if last:
                torn_line = ln
                break
            raise SceneFileError(path, f"line {ln}: corrupt entry in the middle of the log ({e}); "
                                       "earlier entries are intact, later ones cannot be trusted") from None
        ops.append(op)
        pos += len(raw) + 1
        ends.append(pos)
    if tail:  # no newline: the append was interrupted before it was acknowledged
        torn_line = len(complete) + 1
    good = ends[-1] if ends else len(complete[0]) + 1
    return _ParsedLog(header, tuple(ops), good, tuple(ends), torn_line)


def _op_line(op: Op, seq: int) -> bytes:
    d = op_to_json(op)
    d["seq"] = seq
    return (json.dumps(d, separators=(",", ":"), ensure_ascii=False) + "\n").encode()


def _load_base(run_dir: Path) -> BaseLabels:
    from clutt3r_core.runs import missing_run_file

    missing = missing_run_file(run_dir, ("instances.npz", "cloud.npz"))  # the labels are all we need
    if missing is not None:
        raise SceneFileError(missing, "missing: not a clutt3r run folder")
    try:
        with np.load(run_dir / "instances.npz") as a, np.load(run_dir / "cloud.npz") as c:
            return BaseLabels(a["instance"], a["scores"], c["sv_labels"])
    except (OSError, ValueError, KeyError) as e:
        raise SceneFileError(run_dir, f"unreadable run arrays: {e}") from None


class Annotations:
    """The correction layer of one run folder: current labels, history, undo / redo, durable log.

    Thread-safe (one lock): the viewer's tabs share one instance. A writable instance holds an
    exclusive lock on the log; ``close()`` (or the context manager) releases it.
    """

    def __init__(self, run_dir: Path, base: BaseLabels, author: str, readonly: bool) -> None:
        self.run_dir = Path(run_dir)
        self.base = base
        self.author = author
        self.readonly = readonly
        self._lock = threading.RLock()
        self._fd: int | None = None
        self._ops: tuple = ()
        self._log_bytes = 0
        self._header: dict | None = None
        self._labels = _initial(base)
        self._saved_ops = 0  # log entries the snapshot on disk reflects
        self._instances_sha = _file_sha256(self.run_dir / "instances.npz")

    # -- opening ---------------------------------------------------------------------

    @classmethod
    def open(cls, run_dir: str | Path, segmentation=None, author: str = "", readonly: bool = False) -> "Annotations":
        """Open (never create) the corrections of ``run_dir``.

        ``segmentation``: the run's Segmentation / BaseLabels if already loaded (else read from
        instances.npz + cloud.npz). A writable instance recovers a torn last line (warning,
        bytes moved to ops.jsonl.torn) and removes stale snapshot temp files. The log file
        itself is created by the first edit.
        """
        run_dir = Path(run_dir)
        base = BaseLabels.of(segmentation) if segmentation is not None else _load_base(run_dir)
        self = cls(run_dir, base, author or _default_author(), readonly)
        if len(base.instance) != _npz_len(run_dir / "instances.npz"):
            raise SceneFileError(run_dir / "instances.npz", "the given segmentation is not this run's (point count differs)")
        if self.log_path.is_file():
            self._load_log(recover=not readonly)
        return self

    @property
    def log_path(self) -> Path:
        return self.run_dir / LOG_NAME

    @property
    def snapshot_path(self) -> Path:
        return self.run_dir / SNAPSHOT_NAME

    def _load_log(self, recover: bool) -> None:
        path = self.log_path
        if recover:
            self._open_fd()
        parsed = _parse_log(path)
        h = parsed.header
        if h.get("instances_sha256") != self._instances_sha:
            raise SceneFileError(path, "belongs to a different run: instances.npz hash "
                                       f"{str(h.get('instances_sha256'))[:12]}... in the header, "
                                       f"{self._instances_sha[:12]}... on disk")
        if h.get("num_points") != len(self.base.instance):
            raise SceneFileError(path, f"header says {h.get('num_points')} points, the run has {len(self.base.instance)}")
        if parsed.torn_line:
            warnings.warn(CorrectionLogWarning(
                f"{path}: line {parsed.torn_line}: torn or corrupt last line (interrupted write) ignored; "
                f"{len(parsed.ops)} entries kept"), stacklevel=3)
            if recover:
                self._cut_torn_tail(parsed.good_bytes)
        try:
            active_edits(parsed.ops)
        except SceneError as e:
            raise SceneFileError(path, f"line {_line_of(str(e))}: {e}") from None
        self._header, self._ops, self._log_bytes = h, parsed.ops, parsed.good_bytes
        self._labels = self._from_snapshot(parsed) or self._replay(path)
        if recover:
            self._remove_stale_temps()

    def _replay(self, path: Path) -> CorrectedLabels:
        try:
            return apply(self.base, self._ops)
        except SceneError as e:
            raise SceneFileError(path, f"line {_line_of(str(e))}: {e}") from None

    def _from_snapshot(self, parsed: _ParsedLog) -> CorrectedLabels | None:
        p = self.snapshot_path
        if not p.is_file():
            return None
        try:
            with np.load(p) as z:
                n = int(z["num_ops"])
                digest = str(z["log_sha256"])
                if n != len(parsed.ops) or str(z["instances_sha256"]) != self._instances_sha:
                    return None
                lab = CorrectedLabels(z["instance"].astype(np.int32), z["scores"].astype(np.float32),
                                      tuple(str(c) for c in z["categories"]), z["deleted"].astype(bool))
        except (OSError, ValueError, KeyError, SceneError):
            return None  # a cache: an unreadable snapshot is rebuilt from the log
        if digest != _prefix_sha256(self.log_path, parsed.ends[n - 1] if n else _header_end(self.log_path)):
            return None
        if len(lab.instance) != len(self.base.instance):
            return None
        self._saved_ops = n
        return lab

    def _open_fd(self) -> None:
        if self._fd is not None:
            return
        fd = os.open(self.log_path, os.O_RDWR | os.O_APPEND)
        try:
            import fcntl

            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(fd)
            raise CorrectionLogLocked(self.log_path, "is being edited by another process (locked)") from None
        except ImportError:  # no flock on this platform: single-writer is then the user's job
            pass
        self._fd = fd

    def _cut_torn_tail(self, good: int) -> None:
        with open(self.log_path, "rb") as f:
            f.seek(good)
            torn = f.read()
        with open(self.log_path.with_name(self.log_path.name + ".torn"), "ab") as f:
            f.write(torn + b"\n")
            f.flush()
            os.fsync(f.fileno())
        os.ftruncate(self._fd, good)
        os.fsync(self._fd)

    def _remove_stale_temps(self) -> None:
        # atomic_write_bytes leaves '.<name>.*.tmp' behind only if the process died mid-write;
        # we hold the log lock, so no live writer of this run owns them
        for p in self.snapshot_path.parent.glob(f".{self.snapshot_path.name}.*.tmp"):
            try:
                p.unlink()
            except FileNotFoundError:
                pass

    def _create_log(self) -> None:
        header = {
            "format": _FORMAT, "version": _VERSION, "instances_sha256": self._instances_sha,
            "num_points": len(self.base.instance), "num_instances": len(self.base.scores),
            "created": time.time(), "author": self.author,
        }
        data = (json.dumps(header, separators=(",", ":")) + "\n").encode()
        path = self.log_path
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.new")
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        try:
            os.link(tmp, path)  # fails if another writer created it first: never overwrite a log
        except FileExistsError:
            raise SceneFileError(path, "was created by another process meanwhile; reopen the run") from None
        finally:
            os.unlink(tmp)
        _fsync_dir(path.parent)
        self._open_fd()
        self._header, self._log_bytes = header, len(data)

    # -- state -----------------------------------------------------------------------

    @property
    def current(self) -> CorrectedLabels:
        return self._labels

    @property
    def ops(self) -> tuple:
        """Every log entry, in order (edits, undos, redos)."""
        return self._ops

    @property
    def num_ops(self) -> int:
        return len(self._ops)

    @property
    def num_edits(self) -> int:
        """Edits in effect now."""
        return len(active_edits(self._ops)[0])

    @property
    def can_undo(self) -> bool:
        return bool(active_edits(self._ops)[0])

    @property
    def can_redo(self) -> bool:
        return bool(active_edits(self._ops)[1])

    @property
    def saved(self) -> bool:
        """True when the snapshot reflects every log entry (the log itself is always saved)."""
        return self._saved_ops == len(self._ops)

    def history(self) -> tuple[LogEntry, ...]:
        active = set(active_edits(self._ops)[0])
        return tuple(LogEntry(i, op, i in active) for i, op in enumerate(self._ops))

    # -- editing ---------------------------------------------------------------------

    def apply_op(self, op: EditOp) -> CorrectedLabels:
        """Validate ``op`` on the current labels, append it to the log (fsync), then make it current.

        An op with an empty ``author`` is logged with this session's author. Raises SceneError
        (nothing written) if the op does not apply. Undo / Redo: use undo() / redo().
        """
        if isinstance(op, (Undo, Redo)):
            raise SceneError("use Annotations.undo() / redo() for Undo / Redo entries")
        if not op.author:
            op = replace(op, author=self.author)
        with self._lock:
            new = _apply_edit(self.base, self._labels, op)
            self._append(op)
            self._labels = new
            return new

    def undo(self) -> CorrectedLabels:
        """Revert the most recent active edit (appends an Undo entry)."""
        with self._lock:
            active, _ = active_edits(self._ops)
            if not active:
                raise SceneError("nothing to undo")
            op = Undo(active[-1], author=self.author)
            new = apply(self.base, self._ops + (op,))
            self._append(op)
            self._labels = new
            return new

    def redo(self) -> CorrectedLabels:
        """Re-apply the most recently undone edit (appends a Redo entry)."""
        with self._lock:
            _, redo = active_edits(self._ops)
            if not redo:
                raise SceneError("nothing to redo")
            op = Redo(redo[-1], author=self.author)
            new = _apply_edit(self.base, self._labels, self._ops[redo[-1]])
            self._append(op)
            self._labels = new
            return new

    def _append(self, op: Op) -> None:
        if self.readonly:
            raise SceneFileError(self.log_path, "opened read-only")
        if self._fd is None:
            if self.log_path.is_file():
                raise SceneFileError(self.log_path, "appeared after this run was opened; reopen the run")
            self._create_log()
        line = _op_line(op, len(self._ops))
        view = memoryview(line)
        while view:
            n = os.write(self._fd, view)
            view = view[n:]
        os.fsync(self._fd)  # only now does the edit count as done
        self._log_bytes += len(line)
        self._ops = self._ops + (op,)

    def save(self) -> Path:
        """Write the snapshot atomically (reflecting every log entry so far); returns its path."""
        with self._lock:
            if self.readonly:
                raise SceneFileError(self.snapshot_path, "opened read-only")
            lab, n = self._labels, len(self._ops)
            end = self._log_bytes if self._fd is not None else 0
            digest = _prefix_sha256(self.log_path, end) if self._fd is not None else ""
            atomic_write_bytes(self.snapshot_path, npz_bytes(
                instance=lab.instance, scores=lab.scores, categories=np.array(lab.categories, dtype=str),
                deleted=lab.deleted, num_ops=np.int64(n), log_sha256=np.array(digest),
                instances_sha256=np.array(self._instances_sha)))
            self._saved_ops = n
            return self.snapshot_path

    def close(self) -> None:
        with self._lock:
            if self._fd is not None:
                os.close(self._fd)  # also releases the flock
                self._fd = None

    def __enter__(self) -> "Annotations":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            self.close()
        except Exception:
            pass


def _prefix_sha256(path: Path, end: int) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        h.update(f.read(end))
    return h.hexdigest()


def _header_end(path: Path) -> int:
    with open(path, "rb") as f:
        return len(f.readline())


def _npz_len(path: Path) -> int:
    try:
        with np.load(path) as z:
            return int(z["instance"].shape[0])
    except (OSError, ValueError, KeyError) as e:
        raise SceneFileError(path, f"unreadable: {e}") from None


def _line_of(msg: str) -> int:
    # "entry i: ..." -> log line i + 2 (line 1 is the header)
    if msg.startswith("entry "):
        try:
            return int(msg.split()[1].rstrip(":")) + 2
        except ValueError:
            pass
    return 0


def _fsync_dir(d: Path) -> None:
    try:
        fd = os.open(d, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _default_author() -> str:
    try:
        import getpass

        return getpass.getuser()
    except Exception:  # no login name (containers): still a valid, if anonymous, edit
        return "unknown"
