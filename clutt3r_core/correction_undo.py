"""Constant-time undo of correction edits: each edit's inverse delta, and its checkpoint form.

``apply_edit`` returns the labels after an edit and an ``Inverse`` (the points it changed and
their old instance, the instance count before, the category / deleted flags it changed);
``revert`` undoes it in O(changed points + N) without replaying the history. The log
(``clutt3r_core.annotations``) keeps one ``Inverse`` per active edit, and its snapshot stores
them (``inverses_to_arrays``) so that undo stays constant-time after reopening. Split from
``corrections`` (the operations and their replay), which this module builds on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.corrections import (
    BaseLabels,
    CorrectedLabels,
    Delete,
    EditOp,
    Merge,
    Relabel,
    SetCategory,
    Split,
    _apply_edit,
    _check_id,
)
from clutt3r_core.errors import SceneError

__all__ = ["Inverse", "apply_edit", "revert", "inverses_to_arrays", "inverses_from_arrays"]


@dataclass(frozen=True, eq=False)
class Inverse:
    """What one edit changed, enough to revert it in O(changed points + K) (no replay).

    Valid only on the labels right after that edit (the editor's stack discipline guarantees it:
    an edit is undone only when every later edit is undone).

    Attributes:
        points: (M,) int32 point indices whose instance the edit changed.
        old: (M,) int32 their instance before the edit.
        num_instances: K before the edit (a Split appended one id; truncated on revert).
        category: (id, text before) of a SetCategory, (-1, "") otherwise.
        undeleted: ids the edit marked deleted (Merge / Delete), cleared on revert.
    """

    points: np.ndarray
    old: np.ndarray
    num_instances: int
    category: tuple[int, str] = (-1, "")
    undeleted: tuple[int, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "points", np.asarray(self.points, np.int32).reshape(-1))
        object.__setattr__(self, "old", np.asarray(self.old, np.int32).reshape(-1))
        if self.points.shape != self.old.shape:
            raise SceneError("Inverse: points and old must have the same length")


def apply_edit(base: BaseLabels, lab: CorrectedLabels, op: EditOp) -> tuple[CorrectedLabels, Inverse]:
    """``op`` on ``lab`` (pure, new arrays) and its inverse, whatever the history: a Relabel or
    Split costs one copy of the labels + O(selection) (``BaseLabels.selection_indices``), the
    others one vectorised pass. Same result and errors as ``corrections._apply_edit`` (the
    replay; the property tests compare the two)."""
    if isinstance(op, (Relabel, Split)):
        return _apply_sparse(base, lab, op)
    new = _apply_edit(base, lab, op)
    changed = np.flatnonzero(new.instance != lab.instance).astype(np.int32)
    cat = (int(op.instance), lab.categories[op.instance]) if isinstance(op, SetCategory) else (-1, "")
    und = (op.merged if isinstance(op, Merge) else (int(op.instance),) if isinstance(op, Delete) else ())
    return new, Inverse(changed, lab.instance[changed], lab.num_instances, cat, tuple(und))


def _apply_sparse(base: BaseLabels, lab: CorrectedLabels, op) -> tuple[CorrectedLabels, Inverse]:
    name = type(op).__name__
    scores, cats, deleted = lab.scores, lab.categories, lab.deleted
    if isinstance(op, Relabel):
        _check_id(lab, int(op.target), name, allow_none=True)
        val = int(op.target)
        idx = base.selection_indices(op.supervoxels, op.points, name)
    else:
        if op.source is not None:
            _check_id(lab, int(op.source), name, allow_none=True)
        idx = base.selection_indices(op.supervoxels, op.points, name)
        if op.source is not None:
            idx = idx[lab.instance[idx] == op.source]
        if not len(idx):
            raise SceneError(f"{name}: no point to move")
        val = lab.num_instances
        scores = np.append(scores, np.float32(op.score)).astype(np.float32)
        cats = cats + ("",)
        deleted = np.append(deleted, False)
    old = lab.instance[idx]
    ch = idx[old != val].astype(np.int32)
    inst = lab.instance.copy()
    inst[ch] = val
    return (CorrectedLabels(inst, scores, tuple(cats), deleted),
            Inverse(ch, old[old != val], lab.num_instances))


def revert(lab: CorrectedLabels, inv: Inverse) -> CorrectedLabels:
    """The labels before the edit whose inverse is ``inv`` (``lab``: the labels right after it)."""
    inst = lab.instance.copy()
    inst[inv.points] = inv.old
    k = inv.num_instances
    cats = list(lab.categories[:k])
    if inv.category[0] >= 0:
        cats[inv.category[0]] = inv.category[1]
    deleted = lab.deleted[:k].copy()
    if inv.undeleted:
        deleted[list(inv.undeleted)] = False
    return CorrectedLabels(inst, lab.scores[:k].copy(), tuple(cats), deleted)



def inverses_to_arrays(active: list[int], inverse: dict[int, Inverse]) -> dict[str, np.ndarray]:
    """The inverses of the active edits as flat arrays (offsets + concatenation) for the snapshot."""
    invs = [inverse[i] for i in active]
    off = np.cumsum([0] + [len(v.points) for v in invs]).astype(np.int64)
    doff = np.cumsum([0] + [len(v.undeleted) for v in invs]).astype(np.int64)
    cat = lambda f: np.concatenate(f) if f else np.zeros(0, np.int32)  # noqa: E731
    return dict(
        inv_edit=np.asarray(active, np.int64), inv_off=off,
        inv_points=cat([v.points for v in invs]).astype(np.int32), inv_old=cat([v.old for v in invs]).astype(np.int32),
        inv_k=np.asarray([v.num_instances for v in invs], np.int64),
        inv_cat_id=np.asarray([v.category[0] for v in invs], np.int64),
        inv_cat_text=np.array([v.category[1] for v in invs] or [""], dtype=str)[: len(invs)],
        inv_del_off=doff, inv_del=np.asarray([d for v in invs for d in v.undeleted], np.int64))


def inverses_from_arrays(z, active: tuple[int, ...]) -> dict[int, Inverse]:
    """Inverse of ``inverses_to_arrays``; KeyError / SceneError when absent or not these edits."""
    edits = z["inv_edit"]
    # the top of the active stack (the checkpoint keeps the most recent ones only)
    if len(edits) > len(active) or (len(edits) and tuple(edits.tolist()) != tuple(active[-len(edits):])):
        raise SceneError("snapshot inverses are not the active edits")
    off, pts, old, k = z["inv_off"], z["inv_points"], z["inv_old"], z["inv_k"]
    cid, ctext, doff, dl = z["inv_cat_id"], z["inv_cat_text"], z["inv_del_off"], z["inv_del"]
    return {int(e): Inverse(pts[off[j]:off[j + 1]], old[off[j]:off[j + 1]], int(k[j]),
                            (int(cid[j]), str(ctext[j])), tuple(dl[doff[j]:doff[j + 1]].tolist()))
            for j, e in enumerate(edits)}
