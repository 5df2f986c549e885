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

Undo / redo cost O(N + changed points), whatever the history: each active edit keeps its
inverse delta (``clutt3r_core.correction_undo``); the editor's stacks are kept incrementally.
The snapshot is a checkpoint: labels + the active edits' inverses + the number of log entries
it reflects + the SHA-256 of those log bytes (a running hash, so saving never re-reads the
log). Reopening loads it when it is a prefix state of this very log and replays only the
entries after it (undos of older edits included, through the stored inverses).

The operations and their pure replay live in ``clutt3r_core.corrections`` (re-exported here);
this module is the log on disk. It stays one module (about 640 lines) on purpose: the
``Annotations`` class and the log-format helpers share the byte-level invariants above (entry
offsets, the lock, the torn-tail cut, the checkpoint's prefix hash, the stacks the tail
replay continues), which are audited together.
"""

from __future__ import annotations

import hashlib
import json
import os
import threading
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from clutt3r_core.corrections import (  # noqa: F401  (re-exported: the public names of this module)
    BaseLabels,
    CorrectedLabels,
    Delete,
    EditOp,
    Merge,
    Op,
    Redo,
    Relabel,
    SetCategory,
    Split,
    Undo,
    _initial,
    active_edits,
    apply,
    op_from_json,
    op_to_json,
)
from clutt3r_core.correction_undo import Inverse, apply_edit, inverses_from_arrays, inverses_to_arrays, revert
from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import atomic_write_bytes
from clutt3r_core.run_files import CORRECTION_LOG as LOG_NAME

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

SNAPSHOT_NAME = "corrections/instances_corrected.npz"
CHECKPOINT_UNDO_DEPTH = 256  # inverses kept in the checkpoint (ours: a long undo run; measured cost above)
_FORMAT = "clutt3r-corrections"
_VERSION = 1


class CorrectionLogWarning(UserWarning):
    """A torn last line of a correction log was found and ignored (the message names file and line)."""


class CorrectionLogLocked(SceneFileError):
    """Another live process holds the correction log of this run for writing."""


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
    data: bytes = b""  # the file as read (hashed for the snapshot check without a second read)


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
    return _ParsedLog(header, tuple(ops), good, tuple(ends), torn_line, data)


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
        self._ops: list = []
        self._ops_tuple: tuple | None = ()  # cache of tuple(self._ops); None = stale
        # the editor's stacks, kept incrementally (O(1) per entry; active_edits() is their replay)
        self._active: list[int] = []
        self._redo: list[int] = []
        self._inverse: dict[int, Inverse] = {}  # active edit's log index -> how to revert it
        self._log_bytes = 0
        self._log_hash = hashlib.sha256()  # of the log's first _log_bytes bytes (snapshot check)
        self._header: dict | None = None
        self._labels = _initial(base)
        self._saved_ops = 0  # log entries the snapshot on disk reflects
        self._saved_time = 0.0  # time.time() of the last snapshot write (0: none this session)
        self._last_append = 0.0
        self._opened = time.time()
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
        self._header, self._log_bytes = h, parsed.good_bytes
        self._log_hash = hashlib.sha256(parsed.data[: parsed.good_bytes])
        start = self._from_snapshot(parsed)  # entries the checkpoint covers (0: none usable)
        self._ops = list(parsed.ops[:start])
        self._ops_tuple = None
        try:
            for i in range(start, len(parsed.ops)):  # the tail after the checkpoint
                self._step(parsed.ops[i])
                self._ops.append(parsed.ops[i])
        except SceneError as e:
            raise SceneFileError(path, f"line {i + 2}: entry {i}: {e}") from None
        self._ops_tuple = None
        if recover:
            self._remove_stale_temps()

    def _prepare(self, op: Op):
        """(labels after log entry ``op`` (number len(self._ops)), a function that then updates the
        stacks). Pure until that function runs; O(N + changed points), never a replay. Raises
        SceneError if ``op`` does not apply."""
        i = len(self._ops)
        if isinstance(op, Undo):
            if not self._active or self._active[-1] != op.target:
                raise SceneError(f"Undo({op.target}) but the last active edit is "
                                 f"{self._active[-1] if self._active else 'none'}")
            if op.target not in self._inverse:
                self._rebuild_inverses()  # deeper than the checkpoint kept: once, O(active edits)
            new = revert(self._labels, self._inverse[op.target])

            def done() -> None:
                del self._inverse[op.target]
                self._redo.append(self._active.pop())
        elif isinstance(op, Redo):
            if not self._redo or self._redo[-1] != op.target:
                raise SceneError(f"Redo({op.target}) but the last undone edit is "
                                 f"{self._redo[-1] if self._redo else 'none'}")
            new, inv = apply_edit(self.base, self._labels, self._ops[op.target])

            def done() -> None:
                self._inverse[op.target] = inv
                self._active.append(self._redo.pop())
        else:
            new, inv = apply_edit(self.base, self._labels, op)

            def done() -> None:
                self._inverse[i] = inv
                self._active.append(i)
                for j in self._redo:  # dropped for good (a new edit clears the redo stack)
                    self._inverse.pop(j, None)
                self._redo.clear()
        return new, done

    def _rebuild_inverses(self) -> None:
        """Recompute the inverse of every active edit by applying them from the base labels
        (the state they lead to is the current one: the stack discipline)."""
        lab = _initial(self.base)
        inverse = {}
        for i in self._active:
            lab, inverse[i] = apply_edit(self.base, lab, self._ops[i])
        if not lab.equals(self._labels):  # would mean a bug in the inverses or the stacks
            raise SceneError("rebuilt labels differ from the current ones; reopen the run")
        self._inverse = inverse

    def _step(self, op: Op) -> CorrectedLabels:
        new, done = self._prepare(op)
        done()
        self._labels = new
        return new

    def _from_snapshot(self, parsed: _ParsedLog) -> int:
        """Load the checkpoint when it is a state of this very log (its entry count <= the log's and
        the SHA-256 of those log bytes matches); returns the entries it covers (0: not usable, the
        caller replays from the start). The inverses of its active edits come with it, so undo
        stays O(1) after reopening."""
        p = self.snapshot_path
        if not p.is_file():
            return 0
        try:
            with np.load(p) as z:
                n = int(z["num_ops"])
                digest = str(z["log_sha256"])
                if not 0 < n <= len(parsed.ops) or str(z["instances_sha256"]) != self._instances_sha:
                    return 0
                end = parsed.ends[n - 1]
                if digest != hashlib.sha256(parsed.data[:end]).hexdigest():
                    return 0
                lab = CorrectedLabels(z["instance"].astype(np.int32), z["scores"].astype(np.float32),
                                      tuple(str(c) for c in z["categories"]), z["deleted"].astype(bool))
                if len(lab.instance) != len(self.base.instance):
                    return 0
                active, redo = active_edits(parsed.ops[:n])
                inverse = inverses_from_arrays(z, active)
        except (OSError, ValueError, KeyError, SceneError):
            return 0  # a cache: an unreadable or older-format snapshot is rebuilt from the log
        self._labels, self._inverse = lab, inverse
        self._active, self._redo = list(active), list(redo)
        self._saved_ops = n
        return n

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
        self._log_hash = hashlib.sha256(data)

    # -- state -----------------------------------------------------------------------

    @property
    def current(self) -> CorrectedLabels:
        return self._labels

    @property
    def ops(self) -> tuple:
        """Every log entry, in order (edits, undos, redos)."""
        with self._lock:
            if self._ops_tuple is None:
                self._ops_tuple = tuple(self._ops)
            return self._ops_tuple

    @property
    def num_ops(self) -> int:
        return len(self._ops)

    @property
    def num_edits(self) -> int:
        """Edits in effect now."""
        return len(self._active)

    @property
    def can_undo(self) -> bool:
        return bool(self._active)

    @property
    def can_redo(self) -> bool:
        return bool(self._redo)

    @property
    def saved(self) -> bool:
        """True when the snapshot reflects every log entry (the log itself is always saved)."""
        return self._saved_ops == len(self._ops)

    @property
    def saved_ops(self) -> int:
        """Log entries the snapshot (checkpoint) on disk reflects."""
        return self._saved_ops

    @property
    def last_write(self) -> float:
        """time.time() of the last fsynced log append or snapshot write of this instance (0: none)."""
        return max(self._last_append, self._saved_time)

    def history(self) -> tuple[LogEntry, ...]:
        active = set(self._active)
        return tuple(LogEntry(i, op, i in active) for i, op in enumerate(self.ops))

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
            return self._commit(op)

    def undo(self) -> CorrectedLabels:
        """Revert the most recent active edit (appends an Undo entry). O(changed points + N):
        the edit's inverse delta, never a replay of the history."""
        with self._lock:
            if not self._active:
                raise SceneError("nothing to undo")
            return self._commit(Undo(self._active[-1], author=self.author))

    def redo(self) -> CorrectedLabels:
        """Re-apply the most recently undone edit (appends a Redo entry)."""
        with self._lock:
            if not self._redo:
                raise SceneError("nothing to redo")
            return self._commit(Redo(self._redo[-1], author=self.author))

    def _commit(self, op: Op) -> CorrectedLabels:
        # validate and compute on copies first, append (fsync), only then make it current:
        # a failing op changes nothing, a crash after the append is replayed on reopen
        if self.readonly:
            raise SceneFileError(self.log_path, "opened read-only")
        new, done = self._prepare(op)
        self._append(op)
        done()
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
        self._log_hash.update(line)
        self._ops.append(op)
        self._ops_tuple = None
        self._last_append = time.time()

    def save(self) -> Path:
        """Write the snapshot atomically (reflecting every log entry so far); returns its path."""
        with self._lock:
            if self.readonly:
                raise SceneFileError(self.snapshot_path, "opened read-only")
            lab, n = self._labels, len(self._ops)
            # the running hash: O(1) here instead of re-reading the whole log
            digest = self._log_hash.hexdigest() if self._fd is not None else ""
            # uncompressed: a cache rewritten during editing, where zlib over the inverses cost
            # 10x the write (benchmarks/bench_annotations.py)
            atomic_write_bytes(self.snapshot_path, _npz_plain(
                instance=lab.instance, scores=lab.scores, categories=np.array(lab.categories, dtype=str),
                deleted=lab.deleted, num_ops=np.int64(n), log_sha256=np.array(digest),
                instances_sha256=np.array(self._instances_sha),
                **inverses_to_arrays(self._kept_inverses(), self._inverse)))
            self._saved_ops = n
            self._saved_time = time.time()
            return self.snapshot_path

    def _kept_inverses(self) -> list[int]:
        """The active edits whose inverses the checkpoint stores: the top ``CHECKPOINT_UNDO_DEPTH``
        (the undos a reopened session can do at O(1); deeper ones rebuild once). All of them
        made saving and reopening O(every edit's changed points): 0.8 s / 2.4 s at 10k edits
        on 200k points (benchmarks/bench_annotations.py)."""
        top = []
        for i in reversed(self._active[-CHECKPOINT_UNDO_DEPTH:]):
            if i not in self._inverse:
                break
            top.append(i)
        return top[::-1]

    def checkpoint(self, every: int = 64, seconds: float = 30.0) -> bool:
        """Save the snapshot when ``every`` entries or ``seconds`` have passed since the last one
        (an editor calls it after each edit: the log is already durable, the snapshot only makes
        reopening fast, and rewriting it costs O(N + inverse sizes)). True when it saved."""
        with self._lock:
            pending = len(self._ops) - self._saved_ops
            if self.readonly or pending <= 0:
                return False
            if pending >= every or time.time() - max(self._saved_time, self._opened) >= seconds:
                self.save()
                return True
            return False

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


def _npz_plain(**arrays: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


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
