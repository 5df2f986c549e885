"""The labelling an update chain starts from: the run's instances with the user's corrections.

The viewer's Edit tab writes corrections (merge, split, delete, relabel, category) to the run's
append-only log (``clutt3r_core.annotations``, docs/corrections.md). The update's step 0
(``state.state_from_run``) takes the labelling after the log's edits in effect, so an update
after a grasp acts on the instances the user fixed. Its ids are the CORRECTED ids, the ones the
Edit tab shows: a merged id is gone (its points are in the id it joined), a deleted id is gone
(its points are background, -1), a split-off instance has the id the Edit tab gave it (the
number of instances at that time). No renumbering: ``CorrectedLabels.compact`` is for export.

Each state records the labelling it came from (``LabelSource``: log entries replayed, edits in
effect, SHA-256 of the (N,) int32 instance array). The log is append-only, so the labelling of
an older record can be rebuilt exactly by replaying the first ``entries`` entries (the hash
checks it). A correction made after the updates were computed makes the chain stale:
``stale_note`` says so in one line; ``clutt3r update`` refuses to extend a stale chain
(``--recompute`` moves it aside first, never deletes it).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import Mapping

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.run_files import CORRECTION_LOG as LOG_NAME
# the geometry mapping lives in ``update.geometry``; its names stay importable from here (the state,
# the viewer, refine.py and the tests import them from this module)
from clutt3r_core.update.geometry import corrected_geometry_labels, fused_count, geometry_labels, run_geometry

__all__ = ["LabelSource", "RunLabels", "run_labels", "labels_sha256", "chain_source", "labels_change", "stale_note",
           "run_share", "fused_count", "LOG_NAME", "StepZeroLabels", "step_zero_labels", "corrected_geometry_labels",
           "geometry_labels", "gone_reasons"]


def labels_sha256(instance: np.ndarray) -> str:
    """SHA-256 (hex) of an (N,) instance array as little-endian int32 (the labelling's identity)."""
    return hashlib.sha256(np.ascontiguousarray(instance, dtype="<i4").tobytes()).hexdigest()


@dataclass(frozen=True)
class LabelSource:
    """Which labelling a chain's step 0 was built from (``state.json`` "labels").

    Attributes:
        entries: correction log entries replayed (0: no log, the run as segmented).
        active_edits: edits in effect after those entries (undone ones excluded).
        labels_sha256: ``labels_sha256`` of the resulting (N,) instance array over the run's points.
        categories: (id, text) of the instances named in the Edit tab, ascending ids.
    """

    entries: int
    active_edits: int
    labels_sha256: str
    categories: tuple[tuple[int, str], ...] = ()

    @property
    def corrected(self) -> bool:
        return self.active_edits > 0

    def describe(self) -> str:
        if self.entries == 0:
            return "the run as segmented (no corrections)"
        return f"correction log entry {self.entries} ({self.active_edits} edit(s) in effect)"

    def to_json(self) -> dict:
        return {"log": LOG_NAME, "entries": self.entries, "active_edits": self.active_edits,
                "labels_sha256": self.labels_sha256, "categories": {str(k): t for k, t in self.categories}}

    def record(self) -> dict | None:
        """What grasps.json and ``clutt3r query --json`` record as "corrections": ``to_json()``, or None
        with no log entries (the run as segmented). The one record of step 0
        (``StepZeroLabels.to_json``) and of the scenes after updates (``SceneAfter.corrections``)."""
        return self.to_json() if self.entries else None

    @staticmethod
    def from_json(d: dict) -> "LabelSource":
        cats = tuple(sorted((int(k), str(t)) for k, t in (d.get("categories") or {}).items()))
        return LabelSource(int(d["entries"]), int(d["active_edits"]), str(d["labels_sha256"]), cats)


@dataclass(frozen=True, eq=False)
class RunLabels:
    """A run's labelling after some corrections.

    Attributes:
        instance: (N,) int32 instance id per run point (the run's whole cloud), -1 = none.
        ids: (K,) int32 ids that are not deleted and have points, ascending.
        num_ids: ids ever used (deleted and split ones included); new ids start here.
        source: where it came from.
        gone: {id: why it is no instance} for the ids the corrections merged, deleted or emptied
            (``gone_reasons``; empty without a log), so a command refusing such an id after updates
            names the id it joined, as at step 0 (``StepZeroLabels.check_target``).
    """

    instance: np.ndarray
    ids: np.ndarray
    num_ids: int
    source: LabelSource
    gone: Mapping[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        object.__setattr__(self, "gone", MappingProxyType(dict(self.gone)))
        inst = np.asarray(self.instance, np.int32)
        if inst.ndim != 1:
            raise SceneError(f"RunLabels.instance must be (N,), got {inst.shape}")
        ids = np.asarray(self.ids, np.int32)
        if len(inst) and inst.max(initial=-1) >= self.num_ids:
            raise SceneError("RunLabels: instance ids beyond num_ids")
        for name, a in (("instance", inst), ("ids", ids)):
            a = np.ascontiguousarray(a)
            a.setflags(write=False)
            object.__setattr__(self, name, a)


def _base_instance(run_dir: Path, seg) -> np.ndarray:
    if seg is not None:
        return np.asarray(seg.instance, np.int32)
    p = run_dir / "instances.npz"
    try:
        with np.load(p) as z:
            return z["instance"].astype(np.int32)
    except (OSError, ValueError, KeyError) as e:
        raise SceneFileError(p, f"unreadable run labels: {e}") from None


def run_labels(run_dir: str | Path, seg=None, entries: int | None = None) -> RunLabels:
    """The run's labelling after its correction log's first ``entries`` entries (None: all).

    ``seg``: the run's Segmentation when already loaded (else instances.npz / cloud.npz are read).
    Raises ``SceneFileError`` naming the log when it is invalid or shorter than ``entries``."""
    run_dir = Path(run_dir)
    log = run_dir / LOG_NAME
    if not log.is_file():
        if entries:
            raise SceneFileError(log, f"is missing, but the update chain was computed after {entries} of its "
                                      "entries (the corrections were removed?)")
        inst = _base_instance(run_dir, seg)
        n_ids = int(seg.num_instances) if seg is not None else int(inst.max(initial=-1)) + 1
        ids = np.unique(inst[inst >= 0]).astype(np.int32)
        return RunLabels(inst, ids, max(n_ids, len(ids) and int(ids[-1]) + 1), LabelSource(0, 0, labels_sha256(inst)))
    from clutt3r_core.corrections import apply

    ann = _open_log(run_dir, seg)
    ops = ann.ops
    n = len(ops) if entries is None else int(entries)
    if n > len(ops):
        raise SceneFileError(log, f"has {len(ops)} entries, but the update chain was computed after {n} "
                                  "(the log was replaced or cut?)")
    lab = ann.current if n == len(ops) else apply(ann.base, ops[:n])
    return _of_corrected(lab, ops[:n])


def _open_log(run_dir: Path, seg):
    """The run's ``Annotations``, read-only (a torn last line is left to the editor to report)."""
    import warnings

    from clutt3r_core.annotations import Annotations, CorrectionLogWarning

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CorrectionLogWarning)
        return Annotations.open(run_dir, segmentation=seg, readonly=True)


def _of_corrected(lab, ops) -> RunLabels:
    """``RunLabels`` of a ``corrections.CorrectedLabels`` that the log entries ``ops`` give."""
    from clutt3r_core.corrections import active_edits

    counts = lab.point_counts()
    ids = np.flatnonzero(~lab.deleted & (counts > 0)).astype(np.int32)
    cats = tuple((int(k), lab.categories[k]) for k in ids if lab.categories[k])
    return RunLabels(lab.instance, ids, lab.num_instances,
                     LabelSource(len(ops), len(active_edits(ops)[0]), labels_sha256(lab.instance), cats),
                     gone_reasons(ops, lab))


def run_share(labels: np.ndarray, seg, num_ids: int) -> np.ndarray:
    """(num_ids, seg.num_instances) float64: row i = the share of corrected id i's points that
    each run instance had (rows sum to 1; 0 for an id of background points only), counted over
    the run's fused points (``fused_count``: the rim voxels left out, as the update's state leaves
    them out). Carries any per-run-instance quantity (the state's stored embeddings, a
    re-embedding with ``--embedder``, the query's evidence) to corrected ids: a merge mixes its
    parts by size, a split-off part keeps its source's.

    Why without the rim voxels: each is one unverified raw point at a depth edge whose run label
    is its neighbours' vote after the grouping (no mask evidence of its own; on real depth many
    lie just beside their object), and the stored embedding describes the instance the update
    matches, whose points are the fused ones."""
    n = fused_count(seg)
    lab, run = np.asarray(labels)[:n], np.asarray(seg.instance)[:n]
    both = (lab >= 0) & (run >= 0)
    share = np.zeros((int(num_ids), int(seg.num_instances)))
    np.add.at(share, (lab[both], run[both]), 1.0)
    return share / np.maximum(share.sum(axis=1, keepdims=True), 1.0)


def chain_source(run_dir: str | Path) -> tuple[Path, LabelSource | None] | None:
    """(first state folder, the labelling it records) of the run's update chain; None without a
    chain. The record is None for states written before session 7 or from an in-memory
    segmentation (they used the run as segmented)."""
    from clutt3r_core.update.state import state_dirs

    dirs = state_dirs(run_dir)
    if not dirs:
        return None
    p = dirs[0] / "state.json"
    try:
        d = json.loads(p.read_text()).get("labels")
        return dirs[0], (LabelSource.from_json(d) if d else None)
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise SceneFileError(p, f"unreadable labels record: {e}") from None


def _ids(a) -> str:
    a = list(a)
    return ", ".join(f"I{k}" for k in a[:8]) + (f" and {len(a) - 8} more" if len(a) > 8 else "")


def labels_change(then: np.ndarray, now: np.ndarray) -> str | None:
    """What the corrections changed between two (N,) labellings of a run, in a few words
    ("3 point(s) relabelled; no longer instances: I2; new instances: I7"), None when equal."""
    then, now = np.asarray(then), np.asarray(now)
    if then.shape != now.shape:
        return f"the labelling has {len(now)} points, the chain's {len(then)}"
    diff = then != now
    if not diff.any():
        return None
    ids_then, ids_now = np.unique(then[then >= 0]), np.unique(now[now >= 0])
    gone, new = np.setdiff1d(ids_then, ids_now), np.setdiff1d(ids_now, ids_then)
    what = [f"{int(diff.sum())} point(s) relabelled"]
    if len(gone):
        what.append(f"no longer instances: {_ids(gone)}")
    if len(new):
        what.append(f"new instances: {_ids(new)}")
    return "; ".join(what)


def stale_note(run_dir: str | Path, seg=None, frame: int | None = None) -> str | None:
    """One line when the run's update chain was computed from another labelling than the one its
    corrections give now (corrections made after the updates); None when it is current or there
    is no chain. ``frame``: the frame the recompute command names (None: ``F``)."""
    run_dir = Path(run_dir)
    rec = chain_source(run_dir)
    if rec is None:
        return None
    first, then_src = rec
    now = run_labels(run_dir, seg)
    then_entries = then_src.entries if then_src is not None else 0
    if then_src is not None and then_src.labels_sha256 == now.source.labels_sha256:
        return None
    then = run_labels(run_dir, seg, entries=then_entries)
    if then.source.labels_sha256 == now.source.labels_sha256:
        return None
    what = labels_change(then.instance, now.instance)
    n = len(list((run_dir / "updates").glob("*/state.json")))
    f = "F" if frame is None else frame
    return (f"STALE: the {n} update(s) in {run_dir / 'updates'} were computed from {then.source.describe()}; "
            f"the corrections now give {now.source.describe()} ({what}), so their instance ids are "
            f"the old labelling's. Recompute: clutt3r update {run_dir} --frame {f} --recompute "
            f"(moves {first.parent.name}/ aside to updates.stale-<time>/, deletes nothing)")


# -- step 0: the labelling every consumer of a run reads before any update -------------------------


def gone_reasons(ops, lab, corrected: bool = True) -> dict[int, str]:
    """{id: why it is not an instance any more} for the ids of ``lab`` (``corrections.CorrectedLabels``
    after the log entries ``ops``) that are deleted, merged, or (when ``corrected``) left without
    points by the corrections. A merged id names the id it joined and, when that one was merged on
    or deleted since, where its points are now. Entry numbers are 1-based lines of the log."""
    from clutt3r_core.corrections import Delete, Merge, active_edits

    into: dict[int, tuple[int, int]] = {}  # merged id -> (id it joined, log index)
    deleted: dict[int, int] = {}  # deleted id -> log index
    for i in active_edits(ops)[0]:
        op = ops[i]
        if isinstance(op, Merge):
            for o in op.merged:
                into[int(o)] = (int(op.into), i)
        elif isinstance(op, Delete):
            deleted[int(op.instance)] = i
    out: dict[int, str] = {}
    where = f"in the Edit tab ({LOG_NAME} entry"
    for k, i in deleted.items():
        out[k] = f"I{k} was deleted {where} {i + 1}): its points are background"
    for k, (j, i) in into.items():
        end, seen = j, {k}
        while end in into and end not in seen:  # merged on since: follow to the id holding the points now
            seen.add(end)
            end = into[end][0]
        msg = f"I{k} was merged into I{j} {where} {i + 1})"
        if end != j:
            msg += f", which is now part of I{end}"
        out[k] = msg + (f"; I{end} was deleted since" if end in deleted else f": its points are I{end}'s now")
    if corrected:
        counts = lab.point_counts()
        for k in np.flatnonzero((counts == 0) & ~lab.deleted).tolist():
            out.setdefault(int(k), f"I{k} has no points after the corrections in {LOG_NAME} (relabelled away)")
    return out


@dataclass(frozen=True, eq=False)
class StepZeroLabels:
    """The labelling every consumer of a run reads at step 0 (before any update): ``clutt3r query`` /
    ``clutt3r grasp``, the viewer's Query and Grasps tabs (``step_zero_labels``).

    Attributes:
        labels: the run's labelling after its correction log (``RunLabels``: the Edit tab's ids; the
            run's own when there is no log or its edits change nothing). ``labels.instance`` is what
            the Edit tab shows (the contact rule's labels); the query's target points read it.
        seg: the run's ``pipeline.Segmentation``.
        corrected: True when the ids are not the run's own (the edits change labels).
        gone: {id: reason} for ids that are no target (deleted, merged, emptied), ``gone_reasons``.
        pre: ``geometry.run_geometry(seg)`` when already computed (the viewer keeps it).

    Computed once each when first read (the viewer builds one per edit; an edit must not pay for
    them, nor a query for the geometry):

    - ``geometry`` ((N,) int32): the objects' geometry (``geometry.run_geometry``: the labels before
      the weak-echo and contact rules, with the contact fill's points) in the same ids over the run's
      whole cloud, as the update's state reads it (``geometry.geometry_labels``, the one mapping of
      step 0, the state and the scenes after updates); the grasp target of id k is ``geometry == k``
      (a merged id: the union of its parts' geometry). With the run's own ids it is
      ``run_geometry(seg)`` exactly (with the default config: ``refine.run_labels_before_contact``,
      what the grasp target always was).
    - ``share`` ((num_ids, run instances) float64, None when not ``corrected``): ``run_share``, to
      carry per-run-instance evidence to the corrected ids (``query.corrected_evidence``).
    """

    labels: RunLabels
    seg: object = field(repr=False)
    corrected: bool = False
    gone: dict = None  # type: ignore[assignment]
    pre: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        from types import MappingProxyType

        object.__setattr__(self, "gone", MappingProxyType(dict(self.gone or {})))
        if len(self.labels.instance) != len(self.seg.points):
            raise SceneError(f"the corrections have {len(self.labels.instance)} points, the run {len(self.seg.points)}")

    @cached_property
    def geometry(self) -> np.ndarray:
        pre = self.pre
        if pre is None:
            pre = run_geometry(self.seg)
        g = geometry_labels(self.seg, self.labels.instance, pre, self.corrected)
        g.setflags(write=False)
        return g

    @cached_property
    def share(self) -> np.ndarray | None:
        if not self.corrected:
            return None
        s = run_share(self.labels.instance, self.seg, self.labels.num_ids)
        s.setflags(write=False)
        return s

    @property
    def source(self) -> LabelSource:
        return self.labels.source

    def check_target(self, k: int) -> None:
        """One clear ``SceneError`` when id ``k`` cannot be a target (deleted, merged: names the id it
        joined, emptied, out of range)."""
        k = int(k)
        if k in self.gone:
            raise SceneError(f"instance {k} is not a target: {self.gone[k]}")
        n = self.labels.num_ids
        if not 0 <= k < n:
            raise SceneError(f"instance {k} does not exist: the run has instances 0..{n - 1}"
                             + (f" (after {self.source.describe()})" if self.source.entries else ""))

    def target(self, k: int) -> np.ndarray:
        """(N,) bool the grasp target of id ``k``: its points before the contact rule (``check_target``)."""
        self.check_target(k)
        return self.geometry == int(k)

    def describe(self) -> str:
        """"the run as segmented" or "the run as segmented with its corrections (log entry 5, 3 edit(s) in
        effect)" (what the commands print)."""
        src = self.source
        if not src.entries:
            return "the run as segmented"
        return (f"the run as segmented with its corrections (log entry {src.entries}, "
                f"{src.active_edits} edit(s) in effect)")

    def to_json(self) -> dict | None:
        """``LabelSource.record`` of the labelling (what grasps.json records), None without a log."""
        return self.source.record()


def step_zero_labels(seg, run_dir: str | Path | None = None, annotations=None,
                     pre: np.ndarray | None = None) -> StepZeroLabels:
    """The labelling the consumers of a run read at step 0 (``StepZeroLabels``): its correction log's
    edits in effect on ``seg`` (the run's ``pipeline.Segmentation``), read from ``run_dir`` (the log
    on disk) or from ``annotations`` (an open ``annotations.Annotations``: the viewer's live edits).
    Neither, or no log: the run's own labels. The ids stay the run's (``share`` None) when the edits
    change no label; ``geometry`` is then ``geometry.run_geometry(seg)`` exactly (with the default
    config the labels before the contact rule, what the grasp target always was). ``pre``: that
    array when already computed."""
    if annotations is None and run_dir is not None and (Path(run_dir) / LOG_NAME).is_file():
        annotations = _open_log(Path(run_dir), seg)
    lab, ops = None, ()
    if annotations is not None:
        from contextlib import nullcontext

        # one edit's labels with that edit's log entries (the viewer's tabs edit live)
        with getattr(annotations, "_lock", None) or nullcontext():
            lab, ops = annotations.current, annotations.ops
        labels = _of_corrected(lab, ops)
    else:
        inst = np.asarray(seg.instance, np.int32)
        ids = np.unique(inst[inst >= 0]).astype(np.int32)
        labels = RunLabels(inst, ids, int(seg.num_instances), LabelSource(0, 0, labels_sha256(inst)))
    same = np.array_equal(labels.instance, seg.instance)
    # the corrected labelling's reasons (``RunLabels.gone``); with the run's own labels no id is emptied
    gone = (labels.gone if not same else gone_reasons(ops, lab, corrected=False)) if lab is not None else {}
    return StepZeroLabels(labels, seg, not same, gone, pre)
