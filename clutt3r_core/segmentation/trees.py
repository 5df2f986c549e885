"""Per-view instance trees: the containment forest of a view's mask candidates (Sec. III-B.1).

A child is contained in its parent at the pixel level. Real masks are noisy, so
containment has a tolerance: mask i is contained in mask j when at least
``tau_contain`` of i's pixels lie inside j but less than ``tau_contain`` of j's
pixels lie inside i. This implies |i| < |j|, so the relation has no cycles. The
parent of i is its smallest container (lower id on an area tie), i.e. the most
specific one. Consequences, all deterministic and independent of the order the
masks are given in:

- equal or near-equal masks (mutual containment: duplicates, which Grounded SAM
  emits often) are not nested: they are siblings, and each is a leaf unless it
  has children of its own. This matches the original release's trees on the real
  samples (e.g. sample_seq4 frame 0, masks 3 and 10); a group still takes at most
  one of them (one mask per view per group), and the vote drops the other;
- partially overlapping masks (neither contains the other) are not related;
- leaves (nodes with no child) are the proper-segment candidates (Fig. 3: at most
  one proper segment lies on each root-to-leaf path).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.mask_codes import encode_masks
from clutt3r_core.scene import MaskCandidates

__all__ = ["TreeConfig", "InstanceTree", "build_instance_tree", "build_tree_overlaps", "min_mask_area", "mask_overlaps", "mask_codes", "subtree_leaves"]


@dataclass(frozen=True)
class TreeConfig:
    """Instance-tree construction (Sec. III-B.1)."""

    tau_contain: float = 0.85
    """Fraction of a mask's pixels that must lie inside another mask for it to count as
    contained (ours; the paper says "contained within the pixel level" (Fig. 3), i.e. 1.0,
    the ``paper`` preset's value; real Grounded-SAM masks disagree by a few boundary pixels)."""
    min_area_px: int = 0
    """Masks smaller than this many pixels are dropped before the tree is built; 0 = auto,
    0.01 % of the image (ours: single-digit-pixel specks carry no 3D evidence); 1 = keep
    every non-empty mask (the paper's text, which drops none)."""

    def __post_init__(self) -> None:
        if not 0.0 < self.tau_contain <= 1.0:
            raise SceneError(f"TreeConfig.tau_contain must be in (0, 1], got {self.tau_contain}")
        if self.min_area_px < 0:
            raise SceneError(f"TreeConfig.min_area_px must be >= 0 (0 = auto), got {self.min_area_px}")


@dataclass(frozen=True, eq=False)
class InstanceTree:
    """The containment forest of one view.

    Attributes:
        frame: frame index of the view.
        mask_ids: (M,) int32 ids of the masks kept (sorted ascending).
        parent: (M,) int32 index (into mask_ids) of each mask's parent, -1 for roots.
        areas: (M,) int64 pixel areas.
        dropped_ids: (D,) int32 ids of masks dropped before building (too small).
    """

    frame: int
    mask_ids: np.ndarray
    parent: np.ndarray
    areas: np.ndarray
    dropped_ids: np.ndarray

    def __post_init__(self) -> None:
        m = len(self.mask_ids)
        if self.parent.shape != (m,) or self.areas.shape != (m,):
            raise SceneError(f"tree of frame {self.frame}: parent/areas must be ({m},)")
        if m and (self.parent.min() < -1 or self.parent.max() >= m or np.any(self.parent == np.arange(m))):
            raise SceneError(f"tree of frame {self.frame}: invalid parent indices")

    @property
    def is_leaf(self) -> np.ndarray:
        """(M,) bool: the mask has no child."""
        has_child = np.zeros(len(self.mask_ids), bool)
        has_child[self.parent[self.parent >= 0]] = True
        return ~has_child

    @property
    def leaf_ids(self) -> np.ndarray:
        return self.mask_ids[self.is_leaf]

    def index(self, mask_id: int) -> int:
        hit = np.flatnonzero(self.mask_ids == mask_id)
        if not len(hit):
            raise KeyError(f"frame {self.frame} has no mask {mask_id} in its tree")
        return int(hit[0])

    def descendant_leaves(self, i: int) -> np.ndarray:
        """Indices of the leaves in the subtree of node i (i itself if it is a leaf)."""
        return subtree_leaves(self.parent, self.is_leaf)[i]


def subtree_leaves(parent: np.ndarray, is_leaf: np.ndarray) -> list[np.ndarray]:
    """For every node of a forest (parent index, -1 = root), the sorted leaf indices below it
    (itself for a leaf): each leaf is walked up to its root once."""
    out: list[list[int]] = [[] for _ in range(len(parent))]
    for leaf in np.flatnonzero(is_leaf):
        j = int(leaf)
        while j >= 0:
            out[j].append(int(leaf))
            j = int(parent[j])
    return [np.asarray(sorted(x), np.int64) for x in out]


def mask_codes(flat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Factorise the pixels of a (M, P) bool mask stack by the set of masks containing them.

    Returns (label (P,) uint8, uint16 or int64 in 0..C-1, bits (C, M) bool): pixel p lies in mask m iff
    ``bits[label[p], m]`` (``mask_codes.encode_masks``, which ``MaskCandidates`` stores).
    M = 0 gives one empty code.
    """
    flat = np.asarray(flat, bool)
    return encode_masks(flat, flat.shape[1])


def mask_overlaps(masks: np.ndarray | MaskCandidates) -> np.ndarray:
    """(M, M) int64 pixel intersection counts of a (M, H, W) bool stack or of mask candidates
    (diagonal = areas).

    ``MaskCandidates.overlaps``: the pixels factorised by the set of masks containing them (a
    stack is encoded as candidates first), accumulated over the few hundred distinct sets
    instead of M^2 full-image passes.
    """
    if not isinstance(masks, MaskCandidates):
        masks = MaskCandidates(masks, np.arange(len(masks)))
    return masks.overlaps()


def min_mask_area(cfg: TreeConfig, height: int, width: int) -> int:
    """Fewest pixels a mask candidate of a ``height`` x ``width`` view needs to be used at all
    (``TreeConfig.min_area_px``; 0 = 0.01 % of the image, at least 1). The baselines use it too."""
    return cfg.min_area_px if cfg.min_area_px > 0 else max(1, int(round(1e-4 * height * width)))


def build_instance_tree(masks: MaskCandidates, frame: int, cfg: TreeConfig = TreeConfig()) -> InstanceTree:
    """Build the containment forest of one view's mask candidates (Sec. III-B.1)."""
    return build_tree_overlaps(masks, frame, cfg)[0]


def build_tree_overlaps(masks: MaskCandidates, frame: int,
                        cfg: TreeConfig = TreeConfig()) -> tuple[InstanceTree, np.ndarray]:
    """``build_instance_tree`` and the (M, M) int64 pixel overlaps of the kept masks in the
    tree's order (``mask_ids``; diagonal = ``areas``), which the duplicate test reuses."""
    h, w = masks.shape if len(masks) else (0, 0)
    min_area = min_mask_area(cfg, h, w)
    order = np.argsort(masks.ids, kind="stable")  # canonical order: by id, whatever the input order
    ids = masks.ids[order]
    # Overlaps of all masks from the candidates' code image (one pass over its pixels);
    # reordering and dropping then act on the small (M, M) matrix.
    inter = masks.overlaps()[np.ix_(order, order)]
    areas = np.diag(inter).astype(np.int64)
    keep = areas >= min_area
    dropped = ids[~keep]
    ids, areas, inter = ids[keep], areas[keep], inter[np.ix_(keep, keep)]
    m = len(ids)
    parent = np.full(m, -1, np.int32)
    if m:
        frac_in = inter / np.maximum(areas[:, None], 1)  # frac_in[i, j] = |i & j| / |i|
        inside = frac_in >= cfg.tau_contain
        contained = inside & ~inside.T  # mutual containment = duplicates, not nested
        np.fill_diagonal(contained, False)
        # rank: smaller area first, lower id first on ties; the parent is the first container
        rank = np.empty(m, np.int64)
        rank[np.lexsort((ids, areas))] = np.arange(m)
        big = np.iinfo(np.int64).max
        cand_rank = np.where(contained, rank[None, :], big)
        best = cand_rank.min(axis=1)
        has = best < big
        inv = np.empty(m, np.int64)
        inv[rank] = np.arange(m)
        parent[has] = inv[best[has]]
    tree = InstanceTree(
        frame=int(frame),
        mask_ids=ids.astype(np.int32),
        parent=parent,
        areas=areas,
        dropped_ids=dropped.astype(np.int32),
    )
    return tree, inter
