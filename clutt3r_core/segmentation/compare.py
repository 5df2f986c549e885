"""Agreement of two groupings in the original release's ``instance_tree.json`` schema.

Leaf-pair agreement: over the leaves both sides list (same frame and mask id), every
unordered pair is "same instance" or not on each side; precision, recall and F1 of
our "same" pairs against the reference's. Leaves with instance -1 are never "same".

``background_as_instance`` (a second reading, reported next to the strict one, never
instead of it): the original method has no notion of background and groups the table
or tray masks like any object (sample_seq4: one instance of 7 table masks, 21 of the 56
leaf pairs we disagree on), while we flag them background (``clutt3r.background_masks``
in our file) and write them with instance -1. With the option, the leaves our file lists
as background count as one shared instance ("the support"), so two table masks count as
"same" on our side too; where the reference splits them (floor and wall as two
instances) that costs precision, as any merge would. The strict reading stays the
number the benchmarks report.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneFileError

__all__ = ["LeafPairAgreement", "LeafPairDiff", "leaf_pair_agreement", "disagreeing_pairs", "read_leaf2inst",
           "background_leaves"]


@dataclass(frozen=True)
class LeafPairAgreement:
    """Pairwise agreement over common leaves."""

    precision: float
    recall: float
    f1: float
    n_ours: int
    """Leaves we list."""
    n_reference: int
    """Leaves the reference lists."""
    n_common: int
    """Leaves both list (the pairs are over these)."""
    n_pairs_ours: int
    n_pairs_reference: int
    n_pairs_both: int


def read_leaf2inst(tree: dict | str | Path) -> dict[tuple[int, int], int]:
    """(frame, mask) -> instance from an instance_tree.json (path or parsed dict)."""
    tree = _read_tree(tree)
    try:
        return {(int(e["frame"]), int(e["mask"])): int(e["instance"]) for e in tree["initial"]["leaf2inst"]}
    except (KeyError, TypeError) as e:
        raise SceneFileError(Path("instance_tree.json"), f"no initial.leaf2inst list ({e})") from None


def _read_tree(tree: dict | str | Path) -> dict:
    if isinstance(tree, dict):
        return tree
    path = Path(tree)
    try:
        return json.loads(path.read_text())
    except FileNotFoundError:
        raise SceneFileError(path, "file not found") from None
    except json.JSONDecodeError as e:
        raise SceneFileError(path, f"not valid JSON ({e.msg})") from None


def background_leaves(tree: dict | str | Path) -> set[tuple[int, int]]:
    """(frame, mask) of the masks our instance_tree.json lists under ``clutt3r.background_masks``
    (empty for a file without that key, e.g. the original release's)."""
    extra = _read_tree(tree).get("clutt3r") or {}
    try:
        return {(int(e["frame"]), int(e["mask"])) for e in extra.get("background_masks", [])}
    except (KeyError, TypeError) as e:
        raise SceneFileError(Path("instance_tree.json"), f"clutt3r.background_masks: bad entry ({e})") from None


@dataclass(frozen=True)
class LeafPairDiff:
    """One common leaf pair on which the two files disagree.

    ``a``, ``b``: (frame, mask) of the two leaves (``a < b``); ``ours_same``: True when we put
    them in one instance and the reference does not (a false positive of ours), False for the
    reverse; ``ours``, ``reference``: each side's instances of ``a`` and ``b`` (-1 = none).
    """

    a: tuple[int, int]
    b: tuple[int, int]
    ours_same: bool
    ours: tuple[int, int]
    reference: tuple[int, int]


def disagreeing_pairs(ours: dict | str | Path, reference: dict | str | Path,
                      background_as_instance: bool = False) -> tuple[LeafPairDiff, ...]:
    """Every common leaf pair counted against the agreement, in (frame, mask) order (the pairs
    behind ``leaf_pair_agreement``'s precision and recall; ``benchmarks/agreement_pairs.py``
    explains each from a run's trace)."""
    a, b = _instances(ours, reference, background_as_instance)
    common = sorted(set(a) & set(b))
    out = []
    for i, ki in enumerate(common):
        for kj in common[i + 1:]:
            so = a[ki] == a[kj] and a[ki] >= 0
            sr = b[ki] == b[kj] and b[ki] >= 0
            if so != sr:
                out.append(LeafPairDiff(ki, kj, so, (a[ki], a[kj]), (b[ki], b[kj])))
    return tuple(out)


def _instances(ours, reference, background_as_instance: bool):
    ours = _read_tree(ours)
    a, b = read_leaf2inst(ours), read_leaf2inst(reference)
    if background_as_instance:
        bg = background_leaves(ours) & set(a)
        support = max(list(a.values()) + [-1]) + 1
        a = {k: (support if k in bg else v) for k, v in a.items()}
    return a, b


def leaf_pair_agreement(ours: dict | str | Path, reference: dict | str | Path,
                        background_as_instance: bool = False) -> LeafPairAgreement:
    """Leaf-pair agreement of ``ours`` with ``reference`` (module docstring).

    ``background_as_instance``: our leaves listed as background count as one shared instance
    (the second reading of the module docstring); False is the strict reading."""
    a, b = _instances(ours, reference, background_as_instance)
    common = sorted(set(a) & set(b))
    ia = np.array([a[k] for k in common])
    ib = np.array([b[k] for k in common])
    iu = np.triu_indices(len(common), 1)
    same_a = (ia[:, None] == ia[None, :]) & (ia[:, None] >= 0)
    same_b = (ib[:, None] == ib[None, :]) & (ib[:, None] >= 0)
    sa, sb = same_a[iu], same_b[iu]
    both = int((sa & sb).sum())
    p = both / sa.sum() if sa.sum() else 0.0
    r = both / sb.sum() if sb.sum() else 0.0
    f = 2 * p * r / (p + r) if p + r else 0.0
    return LeafPairAgreement(float(p), float(r), float(f), len(a), len(b), len(common),
                             int(sa.sum()), int(sb.sum()), both)
