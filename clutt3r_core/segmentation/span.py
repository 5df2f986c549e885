"""Candidate masks that span two objects: their vote on the other object is not counted (ours, session 9).

Grounded-SAM-like candidates under-segment: in some views one mask covers two touching objects.
The containment trees (Sec. III-B.1) only catch this when the same view also has the separate
masks inside it (the spanning mask is then a parent, no candidate). When it is a leaf it joins
one object's group (it overlaps that object's masks most) and votes, with its full occupancy,
for the other object's super-voxels, where the other object's group is often split or partly
occluded: on fresh generated seeds 10-13 this lost two objects at IoU 0.5 (a sponge under a
mug's masks, a clamp under a Rubik's cube's; docs/benchmark/strict-iou.md, session 8 and 9).

The groups say which masks these are. With ``t = VoteConfig.span_occupancy``:

- mask i *occupies* super-voxel k when o_i(k) >= t; the *footprint* of a group B is the
  non-support super-voxels where B's summed occupancy sum_{j in B} o_j(k) >= t;
- mask i of group A *spans* group B when the super-voxels it occupies hold at least
  ``span_cover`` of the raw points of B's footprint, AND its own group does not confirm it there:
  less than ``span_confirm`` of those points lie in super-voxels that another mask of A also
  occupies. A whole-object group over a fragment group of the same object confirms (its other
  masks cover the fragment too; measured on fresh seeds: median 0.95 of the points); a mask that
  spans a neighbour does not (median 0.01);
- the vote then ignores o_i(k) on the spanned footprint's super-voxels that no other mask of A
  occupies (``SpanningVotes.cleared``); everywhere else, and for every other mask, the vote is
  unchanged. The masks stay in their groups (grouping and confidences do not change).
- session 10 (``VoteConfig.span_instances_only``, on): only a group that is an instance in the
  vote before can be spanned, and on the cleared super-voxels only instances vote. The rule gives an
  object's instance back what a neighbour's mask took; on intermediate + hard seeds 4-5 and 10-17
  every instance session 9's rule created was a one-mask fragment next to its object's own instance
  (a duplicate: a false positive at every IoU).

The rule runs after the fragment absorption (``refine.absorb_fragments``): a fragment of the
mask's own object has joined its group by then, so it is confirmed, not spanned (run before the
absorption, a marker's masks were cleared from its one-mask fragment, which then stayed an instance:
fresh hard_0012 AP50 85.2 -> 78.1). ``span_revote`` votes again on the cleared occupancy, keeps each
instance's confidence from the vote before (the absorption's kept scores), and records the cleared
pairs in the trace (``VoteResult.span_cleared``) so that explanations can name them.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.vote import VoteConfig, VoteResult, keep_scores

__all__ = ["SpanningVotes", "spanning_votes", "cleared_occupancy", "span_revote", "unique_pairs"]


@dataclass(frozen=True, eq=False)
class SpanningVotes:
    """The masks that span another group, and the occupancies the vote ignores.

    Attributes:
        node: (S,) int32 node (trace node index) of each spanning mask; one row per (mask, group) pair.
        group: (S,) int32 the mask's own group (index into the groups).
        spanned: (S,) int32 the group whose footprint it spans.
        cover: (S,) float32 share of the spanned footprint's raw points the mask occupies, in [0, 1].
        confirm: (S,) float32 share of those points that another mask of its own group occupies.
        cleared: (C, 2) int32 (node, super-voxel) pairs whose occupancy the vote ignores, sorted, unique.
    """

    node: np.ndarray
    group: np.ndarray
    spanned: np.ndarray
    cover: np.ndarray
    confirm: np.ndarray
    cleared: np.ndarray

    def __post_init__(self) -> None:
        s = len(self.node)
        for name in ("group", "spanned", "cover", "confirm"):
            if getattr(self, name).shape != (s,):
                raise SceneError(f"SpanningVotes.{name} must have shape ({s},), got {getattr(self, name).shape}")
        if self.cleared.ndim != 2 or self.cleared.shape[1] != 2:
            raise SceneError(f"SpanningVotes.cleared must have shape (C, 2), got {self.cleared.shape}")


def _empty() -> SpanningVotes:
    z = np.zeros(0, np.int32)
    return SpanningVotes(z, z.copy(), z.copy(), np.zeros(0, np.float32), np.zeros(0, np.float32),
                         np.zeros((0, 2), np.int32))


def spanning_votes(
    groups: tuple[tuple[int, ...], ...],
    occupancy: np.ndarray,
    sv_counts: np.ndarray,
    support: np.ndarray,
    eligible: np.ndarray,
    min_cover: float,
    max_confirm: float,
    occupied: float = 0.5,
    spannable: np.ndarray | None = None,
    node_view: np.ndarray | None = None,
    min_views: int = 0,
    confirm_apart: float = 0.0,
) -> SpanningVotes:
    """Masks of each group that span another group's footprint (module docstring).

    groups: node-index tuples (the final grouping); occupancy: (U, K) o_i(k) in [0, 1];
    sv_counts: (K,) raw points per super-voxel; support: (K,) bool (never part of a footprint);
    eligible: (G,) bool groups that vote (``min_group_size``): only they can be spanned or span;
    min_cover, max_confirm, occupied: ``VoteConfig.span_cover``, ``span_confirm``,
    ``span_occupancy``. ``min_cover`` <= 0 gives no spanning mask (the rule is off).
    spannable: (G,) bool groups that may be spanned (``VoteConfig.span_instances_only``: the
    instances of the vote before); None = every eligible group.
    node_view, min_views: (U,) view of each node; a mask spans only when the other masks of its group
    come from at least ``min_views`` distinct views (``VoteConfig.span_min_views``; 0 = no minimum).
    confirm_apart: when the masks of a group that cover ``min_cover`` of a footprint are at most this
    share of the group's masks, only its other masks confirm there (``VoteConfig.span_confirm_apart``;
    0 = off): a few views' masks that all span a neighbour do not confirm each other.
    """
    occ = np.asarray(occupancy, np.float32)
    u, k = occ.shape
    g = len(groups)
    if min_cover <= 0 or g < 2 or not k:
        return _empty()
    if len(sv_counts) != k or len(support) != k or len(eligible) != g:
        raise SceneError(f"spanning_votes: sv_counts / support need ({k},) and eligible ({g},), got "
                         f"{np.shape(sv_counts)}, {np.shape(support)}, {np.shape(eligible)}")
    if spannable is not None and np.shape(spannable) != (g,):
        raise SceneError(f"spanning_votes: spannable needs ({g},), got {np.shape(spannable)}")
    if min_views > 0 and (node_view is None or np.shape(node_view) != (u,)):
        raise SceneError(f"spanning_votes: min_views needs node_view ({u},), got {np.shape(node_view)}")
    pts = np.where(np.asarray(support, bool), 0.0, np.asarray(sv_counts, np.float64))
    member = np.full(u, -1, np.int64)
    for gi, m in enumerate(groups):
        member[list(m)] = gi
    nodes = np.flatnonzero((member >= 0) & np.asarray(eligible, bool)[np.maximum(member, 0)])
    if not len(nodes):
        return _empty()
    # only the non-support super-voxels some voting mask puts occupancy on can be in a footprint
    live = np.flatnonzero((pts > 0) & (occ[nodes].max(axis=0) > 0))
    occ_n, pts = occ[np.ix_(nodes, live)], pts[live]
    f_i = occ_n >= occupied  # (n, C) super-voxels each mask occupies
    onehot = np.zeros((g, len(nodes)), np.float32)  # (G, n) group membership (np.add.at is slow on rows)
    onehot[member[nodes], np.arange(len(nodes))] = 1.0
    gsum = onehot @ occ_n
    fb = (gsum >= occupied) & np.asarray(eligible, bool)[:, None]  # (G, C) footprints
    count = np.rint(onehot @ f_i.astype(np.float32)).astype(np.int64)
    confirmed = f_i & (count[member[nodes]] - f_i >= 1)  # another mask of the same group occupies it
    fb_pts = fb.astype(np.float64) @ pts  # (G,)
    fbt = fb.T.astype(np.float64)
    over = (f_i * pts) @ fbt  # (n, G) points of X = F_i & F_B
    conf = (confirmed * pts) @ fbt
    cover = over / np.maximum(fb_pts, 1e-12)[None, :]
    conf_of = None
    if confirm_apart > 0:  # per footprint B: confirmation only from masks that do not span B themselves
        conf_of = {}
        sizes = onehot.sum(axis=1)  # (G,) voting masks per group
        for b in np.flatnonzero((cover >= min_cover).any(axis=0) & (fb_pts > 0)).tolist():
            spans_b = cover[:, b] >= min_cover
            few = (onehot @ spans_b.astype(np.float32)) <= confirm_apart * sizes + 1e-6  # (G,) few span b
            f_ns = f_i & ~(spans_b & few[member[nodes]])[:, None]
            cnt_b = np.rint(onehot @ f_ns.astype(np.float32)).astype(np.int64)
            conf_of[b] = f_i & (cnt_b[member[nodes]] - f_ns >= 1)
            conf[:, b] = (conf_of[b] * pts) @ fbt[:, b]
    confirm = conf / np.maximum(over, 1e-12)
    span = (cover >= min_cover) & (confirm < max_confirm) & (fb_pts > 0)[None, :]
    if spannable is not None:
        span &= np.asarray(spannable, bool)[None, :]
    if min_views > 0:
        span &= (_other_views(groups, member, nodes, np.asarray(node_view)) >= min_views)[:, None]
    span[np.arange(len(nodes)), member[nodes]] = False  # a group does not span itself
    rows, cols = np.nonzero(span)
    if not len(rows):
        return _empty()
    pairs = []
    for r, b in zip(rows.tolist(), cols.tolist()):
        sv = live[f_i[r] & fb[b] & ~(confirmed[r] if conf_of is None else conf_of[b][r])]
        pairs.append(np.stack([np.full(len(sv), nodes[r]), sv], axis=1))
    cleared = unique_pairs(pairs, k)
    return SpanningVotes(
        node=nodes[rows].astype(np.int32),
        group=member[nodes[rows]].astype(np.int32),
        spanned=cols.astype(np.int32),
        cover=cover[rows, cols].astype(np.float32),
        confirm=confirm[rows, cols].astype(np.float32),
        cleared=cleared,
    )


def unique_pairs(parts, k: int) -> np.ndarray:
    """(C, 2) int32 the (node, super-voxel) pairs of ``parts`` (a list of (n_i, 2) int arrays),
    each once, sorted by node then super-voxel; ``k``: the number of super-voxels (> every one)."""
    both = np.concatenate([np.asarray(p, np.int64).reshape(-1, 2) for p in parts])
    flat = np.unique(both[:, 0] * k + both[:, 1])
    return np.stack([flat // k, flat % k], axis=1).astype(np.int32)


def _other_views(groups: tuple[tuple[int, ...], ...], member: np.ndarray, nodes: np.ndarray,
                 node_view: np.ndarray) -> np.ndarray:
    """(n,) int distinct views among the other masks of each node's group (a group may hold two
    near-identical masks of one view: ``grouping.duplicate_iou``)."""
    out = np.zeros(len(nodes), np.int64)
    for r, i in enumerate(nodes.tolist()):
        out[r] = len({int(node_view[j]) for j in groups[int(member[i])] if j != i})
    return out


def cleared_occupancy(occupancy: np.ndarray, cleared: np.ndarray) -> np.ndarray:
    """(U, K) float32 copy of ``occupancy`` with o_i(k) = 0 at every (node, super-voxel) pair of
    ``cleared`` ((C, 2) int); the occupancy itself when there is none."""
    if not len(cleared):
        return occupancy
    out = np.array(occupancy, np.float32, copy=True)
    out[cleared[:, 0], cleared[:, 1]] = 0.0
    return out


def span_revote(
    groups: tuple[tuple[int, ...], ...],
    occupancy: np.ndarray,
    sv_counts: np.ndarray,
    support: np.ndarray,
    vote: VoteResult,
    vote_on: Callable[[np.ndarray], VoteResult],
    cfg: VoteConfig,
    node_view: np.ndarray | None = None,
    n_views: int = 0,
) -> VoteResult:
    """The vote on ``groups`` again with the spanning masks' occupancies cleared (module docstring).

    vote: the vote on these groups so far (after the absorption); vote_on(occupancy) runs the
    pipeline's ``supervoxel_vote`` on ``groups`` with another (U, K) occupancy. Each instance keeps
    its confidence from ``vote`` (instances renumbered by it, ties to the lower id); the result
    records ``span_cleared`` ((0, 2) when no mask spans: then it is ``vote`` otherwise unchanged).
    With ``cfg.span_instances_only`` only the instances of ``vote`` can be spanned, and only they vote
    on the cleared super-voxels (``_instances_take``; those pairs are recorded too). node_view (U,)
    and n_views: each node's view and the views segmented (``cfg.span_min_views``; None / 0 = no minimum).
    """
    eligible = np.array([len(m) >= cfg.min_group_size for m in groups], bool)
    spannable = None
    if cfg.span_instances_only:  # only a group the vote made an instance gets super-voxels back
        spannable = np.zeros(len(groups), bool)
        spannable[np.asarray(vote.instance_group, np.int64)] = True
    min_views = int(np.ceil(cfg.span_min_views * n_views - 1e-9)) if node_view is not None else 0
    span = spanning_votes(groups, occupancy, sv_counts, support, eligible, cfg.span_cover, cfg.span_confirm,
                          cfg.span_occupancy, spannable, node_view, min_views, cfg.span_confirm_apart)
    if not len(span.cleared):
        return replace(vote, span_cleared=span.cleared)
    cleared = span.cleared
    if spannable is not None:
        cleared = _instances_take(groups, occupancy, cleared, spannable)
    new = vote_on(cleared_occupancy(occupancy, cleared))
    before = {groups[int(g)]: float(s) for g, s in zip(vote.instance_group, vote.scores)}
    return replace(keep_scores(new, groups, before), span_cleared=cleared)


def _instances_take(groups: tuple[tuple[int, ...], ...], occupancy: np.ndarray, cleared: np.ndarray,
                    instance: np.ndarray) -> np.ndarray:
    """``cleared`` ((C, 2) node, super-voxel) plus every occupied pair of a mask of a group that is
    not an instance (``instance``: (G,) bool) on the cleared super-voxels, sorted and unique: what a
    spanning mask no longer votes for goes to an instance or to nobody, never to a group that won
    nothing before (session 10: a one-mask fragment of the spanning mask's object, 17 raw points,
    took one cleared super-voxel and became a second instance of that object, hard_0003)."""
    others = np.array([j for gi, m in enumerate(groups) if not instance[gi] for j in m], np.int64)
    if not len(others):
        return cleared
    ks = np.unique(cleared[:, 1])
    r, c = np.nonzero(np.asarray(occupancy)[np.ix_(others, ks)] > 0)
    if not len(r):
        return cleared
    return unique_pairs([cleared, np.stack([others[r], ks[c]], axis=1)], np.asarray(occupancy).shape[1])
