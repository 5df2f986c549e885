"""Agreement of two groupings in the original release's ``instance_tree.json`` schema.

Leaf-pair agreement: over the leaves both sides list (same frame and mask id), every
unordered pair is "same instance" or not on each side; precision, recall and F1 of
our "same" pairs against the reference's. Leaves with instance -1 are never "same".
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneFileError

__all__ = ["LeafPairAgreement", "leaf_pair_agreement", "read_leaf2inst"]


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
    if not isinstance(tree, dict):
        path = Path(tree)
        try:
            tree = json.loads(path.read_text())
        except FileNotFoundError:
            raise SceneFileError(path, "file not found") from None
        except json.JSONDecodeError as e:
            raise SceneFileError(path, f"not valid JSON ({e.msg})") from None
    try:
        return {(int(e["frame"]), int(e["mask"])): int(e["instance"]) for e in tree["initial"]["leaf2inst"]}
    except (KeyError, TypeError) as e:
        raise SceneFileError(Path("instance_tree.json"), f"no initial.leaf2inst list ({e})") from None


def leaf_pair_agreement(ours: dict | str | Path, reference: dict | str | Path) -> LeafPairAgreement:
    a, b = read_leaf2inst(ours), read_leaf2inst(reference)
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
