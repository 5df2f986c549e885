"""Duplicate masks: near-identical masks of one view are one mask (ours, issue 13).

Grounded SAM often returns the same mask twice in one view (two boxes, one mask each, a
few boundary pixels apart). The containment tree keeps such copies as siblings (mutual
containment, ``segmentation.trees``), which goes wrong in two ways, both measured on the
real samples:

- **leaf copies**: both are leaves, and the one-mask-per-view rule then forces them into two
  different groups: the object becomes two instances, each taking one copy per view, and
  which copy goes where is arbitrary. sample_seq1: the green clamp has two copies (pixel IoU
  0.977-0.991) in 7 of 8 views; all 20 leaf pairs on which we disagreed with the original
  release's trees were pairs of these copies. Fix: the copies start the grouping as one group.
- **childless copies of a parent**: the tree gives the children to the smallest of the
  near-equal containers, and the other copies stay childless, i.e. leaves, i.e. proper-segment
  candidates. sample_seq4: a mustard-and-banana mask emitted 2-3 times per view (IoU 0.95-0.97)
  left a childless copy in 5 views; those grouped as an extra "object" that covered both.
  Fix: a leaf copy that contains one of the parent's children (by the tree's own
  containment rule) is no candidate (``Duplicates.shadow``).

Two masks are copies when their pixel IoU is at least ``GroupingConfig.duplicate_iou`` (0.9:
the copies above are >= 0.95, while a union of an object and a sliver of its neighbour, a
different candidate, measured 0.88).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["DuplicatePair", "Duplicates", "duplicate_masks", "pixel_iou"]


@dataclass(frozen=True)
class DuplicatePair:
    """Two leaves (node indices, ``a < b``) of one view with pixel IoU ``iou`` (unitless, 0-1)."""

    a: int
    b: int
    iou: float

    def __post_init__(self) -> None:
        if not 0 <= self.a < self.b:
            raise SceneError(f"DuplicatePair needs 0 <= a < b, got {self.a}, {self.b}")


def pixel_iou(a: np.ndarray, b: np.ndarray, area_a: int | None = None, area_b: int | None = None,
              buf: np.ndarray | None = None) -> float:
    """IoU of two (H, W) bool masks (0 when either is empty). ``area_a``/``area_b``: their pixel
    counts when known; ``buf``: an (H, W) bool scratch array (no allocation per call)."""
    sa = int(np.count_nonzero(a)) if area_a is None else int(area_a)
    sb = int(np.count_nonzero(b)) if area_b is None else int(area_b)
    return _iou(int(np.count_nonzero(np.logical_and(a, b, out=buf))) if sa and sb else 0, sa, sb)


def _iou(inter: int, sa: int, sb: int) -> float:
    """IoU from pixel counts: intersection ``inter``, areas ``sa`` and ``sb`` (0 when either is empty)."""
    if not sa or not sb:
        return 0.0
    return inter / (sa + sb - inter)


@dataclass(frozen=True, eq=False)
class Duplicates:
    """Near-identical masks of one view (``duplicate_masks``).

    Attributes:
        pairs: leaf pairs to join (both leaves, in a duplicate set without a parent), by node
            index, in canonical order.
        shadow: (U,) bool leaves that duplicate a mask with children: the same mask as a parent,
            so not a proper-segment candidate (the pipeline clears their ``is_leaf``).
    """

    pairs: tuple[DuplicatePair, ...]
    shadow: np.ndarray


def duplicate_masks(
    view: np.ndarray, parent: np.ndarray, is_leaf: np.ndarray, background: np.ndarray,
    overlaps: list[np.ndarray] | tuple[np.ndarray, ...], tau: float, tau_contain: float,
) -> Duplicates:
    """Sets of near-identical non-background masks of one view (pixel IoU >= ``tau``, connected).

    view: (U,) int view of each node (nodes in canonical order, grouped by view);
    parent, is_leaf, background: (U,) as in ``grouping.NodeTable``;
    overlaps: per view, the (M_v, M_v) int64 pixel intersection counts of that view's node
        masks in node order, diagonal = areas (``trees.build_tree_overlaps``, which the tree
        builder computes anyway; ``trees.mask_overlaps`` of a stack);
    tau: IoU threshold in (0, 1]; 0 = off (nothing found);
    tau_contain: the trees' containment fraction (``TreeConfig.tau_contain``).

    A set of leaves only is one candidate (``pairs``: joined in the grouping). A leaf in a set
    that holds a mask with children is a copy of that parent (``shadow``) when it contains one
    of the parent's children by the tree's own rule (>= ``tau_contain`` of the child's pixels
    inside it): the tree gave the children to the smallest of the near-equal containers and left
    the other copies childless (sample_seq4: a mustard-and-banana mask emitted 2-3 times per
    view). A leaf that does not contain the parent's children (an object B beside the union
    of B and a small neighbour T, whose child is T) stays a candidate.

    Every count comes from ``overlaps``: no pixel is visited here (it was a few whole-image
    ANDs per view, recomputing what the trees had counted and thrown away).
    """
    view = np.asarray(view)
    is_leaf = np.asarray(is_leaf, bool)
    shadow = np.zeros(len(view), bool)
    if tau <= 0:
        return Duplicates((), shadow)
    if not 0 < tau <= 1:
        raise SceneError(f"duplicate IoU threshold must be in (0, 1], got {tau}")
    usable = ~np.asarray(background, bool)
    pairs: list[DuplicatePair] = []
    for v, inter in enumerate(overlaps):
        nodes_v = np.flatnonzero(view == v)
        if inter.shape != (len(nodes_v), len(nodes_v)):
            raise SceneError(f"view {v}: overlaps of shape {inter.shape} for {len(nodes_v)} nodes")
        local = np.flatnonzero(usable[nodes_v])
        if len(local) < 2:
            continue
        area = [int(inter[i, i]) for i in local]
        found: list[DuplicatePair] = []
        for x in range(len(local)):
            for y in range(x + 1, len(local)):
                lo, hi = sorted((area[x], area[y]))
                if not lo or lo < tau * hi:  # IoU <= smaller / larger
                    continue
                iou = _iou(int(inter[local[x], local[y]]), area[x], area[y])
                if iou >= tau:
                    found.append(DuplicatePair(int(nodes_v[local[x]]), int(nodes_v[local[y]]), float(iou)))
        for comp in _components(found):
            if is_leaf[comp].all():
                pairs += [p for p in found if p.a in comp]
                continue
            first = int(nodes_v[0])
            children = [int(c) for c in np.flatnonzero(np.isin(parent, comp[~is_leaf[comp]]))]
            for leaf in comp[is_leaf[comp]]:
                lf = int(leaf) - first
                if any(_contained(inter, c - first, lf, tau_contain) for c in children):
                    shadow[leaf] = True
    return Duplicates(tuple(pairs), shadow)


def _contained(inter: np.ndarray, child: int, container: int, tau_contain: float) -> bool:
    """At least ``tau_contain`` of mask ``child``'s pixels lie inside mask ``container``
    (both indices into the view's overlap matrix ``inter``)."""
    n = int(inter[child, child])
    return n > 0 and int(inter[child, container]) >= tau_contain * n


def _components(pairs: list[DuplicatePair]) -> list[np.ndarray]:
    """Connected node sets of the duplicate relation (sorted node indices)."""
    root: dict[int, int] = {}

    def find(x: int) -> int:
        while root.setdefault(x, x) != x:
            x = root[x]
        return x

    for p in pairs:
        ra, rb = find(p.a), find(p.b)
        if ra != rb:
            root[max(ra, rb)] = min(ra, rb)
    comps: dict[int, list[int]] = {}
    for x in sorted(root):
        comps.setdefault(find(x), []).append(x)
    return [np.array(c, np.int64) for c in comps.values()]
