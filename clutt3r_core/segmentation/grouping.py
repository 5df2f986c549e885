"""Cross-view grouping of tree leaves and residual-node parent substitution
(Sec. III-B.2 and III-B.3, Algorithm 1).

Nodes are the masks of all trees (``NodeTable``); grouping starts from the leaves.
Similarities are leaf-level matrices over all nodes; a group's edge to another
group is the mean of the member-pair similarities (GroupAndRewire, mean linkage).

The one rule we add to the paper's text, and why: **a group holds at most one mask
per view.** Two groups whose view sets intersect have no edge, so a merge never
puts two masks of one view together. The paper's phi(.) forbids edges between
leaves of one frame; the original release's trees obey the stronger rule without
exception, and allowing two masks of a view in a group lets stage 2 merge whole
same-coloured objects (shared/notes/grouping-findings.md, point 1).

Determinism: nodes are indexed in canonical order (frame, mask id), groups are
kept sorted by their first member, and ties on the best score go to the first pair
in that order, so the result does not depend on the order masks or views arrive in.

It stays one module (about 680 lines) on purpose: both stages, the rewiring, the
substitution rounds and the decision records share the group bookkeeping, and
Algorithm 1 reads best top to bottom in one place.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.decisions import (
    BLOCK_RULES,
    RESIDUAL_REASONS,
    BlockedPairs,
    ResidualNotes,
    StageStop,
    stop_record,
)
from clutt3r_core.segmentation.duplicates import DuplicatePair
from clutt3r_core.segmentation.trees import subtree_leaves

__all__ = [
    "GroupingConfig",
    "NodeTable",
    "SimilarityGraph",
    "MergeStep",
    "Substitution",
    "GroupingResult",
    "spatial_similarity",
    "semantic_similarity",
    "group_nodes",
    "substitute_residuals",
    "stranded_parents",
    "run_grouping",
    "reunion_weights",
    "same_view_containment",
    "StageStop",
    "BlockedPairs",
    "ResidualNotes",
    "BLOCK_RULES",
    "RESIDUAL_REASONS",
]

STAGE_SPATIAL = 0
STAGE_SEMANTIC = 1
STAGE_NAMES = ("spatial", "semantic")

@dataclass(frozen=True)
class GroupingConfig:
    """Two-stage grouping and substitution (Sec. III-B.2, III-B.3; thresholds Sec. IV)."""

    tau_spat: float = 0.5
    """Sec. IV, tau_spat: stage 1 merges while the best mean S_spatial >= this."""
    tau_sem: float = 0.65
    """Sec. IV, tau_sem: stage 2 merges while the best mean S_semantic >= this."""
    use_spatial: bool = True
    """False = the paper's "w/o S_spatial" ablation (Table III): stage 1 is skipped."""
    use_semantic: bool = True
    """False skips stage 2 (ours, for diagnosis)."""
    substitution: bool = True
    """False = the paper's "w/o substitution" ablation (Table III)."""
    substitution_rounds: int = 1
    """Sec. III-B.3: "converges within a single iteration"; more rounds climb further up the trees."""
    one_mask_per_view: bool = True
    """Ours, stated in the module docstring; False lets groups share views (for the ablation only)."""
    reunion_tau: float = 0.0
    """Ours, off by default (0 = off): after substitution, merge groups that SHARE views (an object
    split into parts in several views, which the one-mask-per-view rule cannot join) when their
    mean S_spatial over cross-view pairs is >= this. Measured at 0.25: generated held-out seeds
    20-25 gain 1.6-3.4 AP (harsh easy loses 1.1), but on real sample_seq4 it joins the mustard
    bottle with a touching object (leaf-pair F1 0.881 -> 0.872, precision 0.905 -> 0.851), so it
    stays off: real depth noise lets touching objects overlap in 3D. Session 10: that pair is a
    mustard-and-banana leaf copy holding the mustard's mask (``reunion_max_contain`` keeps it out),
    and reunited groups rank by views (``reunion_weights``). With the gate at 0.5 and tau 0.25:
    tuning seeds 2-3 AP 54.18 -> 55.06, check seeds 0-1 identical (56.34), fresh seeds 10-17
    (intermediate + hard) 52.25 -> 54.11, AP50 92.49 -> 94.85; clean depth and both real samples
    identical. The lead's held-out seeds 6-9 and 18-21 (24 scenes): AP 62.5 / 58.1 / 45.7 -> 63.8 / 58.9 /
    46.1, intermediate AP50 96.3 -> 97.5, hard AP50 86.0 -> 85.96, AP25 not lower, no scene lower by more
    than 0.6 AP. Off: the check seeds did not rise, and the reunion's failure mode is real depth (two
    touching objects overlapping in 3D), which two real sequences cannot rule out
    (docs/benchmark/strict-iou.md, "Session 10: splits" and the lead's check after it)."""
    reunion_max_contain: float = 1.0
    """Ours (session 10), read only with ``reunion_tau`` > 0; 1 = no gate: two groups are reunited
    only when, in every view they share, their two masks' pixel intersection over the smaller
    mask's area (unitless) is under this. The parts of one split object are side by side in a
    view (measured on fresh seeds: see docs/benchmark/strict-iou.md, "Session 10: splits"); the
    pair that made ``reunion_tau`` fail on sample_seq4 is a mustard-and-banana leaf copy holding
    the mustard's mask of the same view (containment 1.0). Needs the views' pixel overlaps
    (``run_grouping``'s ``overlaps``); without them the gate blocks nothing."""
    reunion_min_semantic: float = -1.0
    """Ours (session 10), read only with ``reunion_tau`` > 0; -1 = no gate: the reunion also needs
    the pair's mean S_semantic (eq. 3, unitless) >= this (splits measured 0.73-0.96, the touching
    pair with the highest S_spatial 0.60; docs/benchmark/strict-iou.md, "Session 10: splits").
    With tau 0.12 and containment 0.5: tuning AP 54.18 -> 55.01, check identical, fresh seeds
    10-17 52.25 -> 55.07, real samples identical; off like the reunion."""
    semantic_needs_overlap: bool = True
    """Ours: stage 2 only merges groups whose mean S_spatial is above 0, i.e. whose masks share
    at least one super-voxel in 3D. Sec. III-B.2 uses S_spatial "to resolve ambiguities among
    same-category duplicates"; without this gate stage 2 joins look-alike objects that never
    touch (measured: every wrong stage-2 merge on generated hard scenes had S_spatial = 0 exactly,
    every right one >= 0.17). False = the paper's text."""
    semantic_min_spatial: float = 0.01
    """Ours (session 8, the default since session 9; 0 = only ``semantic_needs_overlap``'s > 0):
    stage 2 also needs the groups' mean S_spatial (eq. 2, unitless) >= this. On fresh generated
    seeds 10-13 two of the eight objects with no prediction at IoU 0.5 were joined to a neighbour
    by a stage-2 merge whose mean S_spatial was above 0 but under 0.003 (a stray mask of the
    neighbour sharing a super-voxel or two; ``benchmarks/ap50_misses.py``), then absorbed into the
    neighbour; stage-2 merges under 0.01 were wrong 11 times of 12 (tuning and fresh seeds).
    Measured (docs/benchmark/strict-iou.md, "Session 9"): the lead's held-out seeds 6-9
    intermediate AP25 / AP50 / AP 94.8 / 88.6 / 51.0 -> 97.3 / 92.5 / 53.0, easy and hard equal
    (AP25 +0.1); fresh seeds 10-13 AP50 91.4 -> 93.6; check seeds 0-1 identical; tuning seeds 2-3
    AP 53.70 -> 53.50 (a stray mask kept out lowers one group's confidence: a ranking change);
    real samples identical. Needs ``semantic_needs_overlap``; a pair it blocks is recorded as the
    overlap gate's (``BlockedPairs``, rule ``overlap_gate``)."""
    spatial_excludes_support: bool = True
    """Ours (findings point 4): S_spatial (eq. 2) is computed with the support super-voxels'
    occupancy set to 0 (table and tray carry no evidence of object identity; two masks that
    both bleed onto the table must not look alike for it). Read by the pipeline when it builds
    the leaf graph; no effect when nothing is marked support. False = the paper's eq. 2 over
    every super-voxel."""
    duplicate_iou: float = 0.9
    """Ours (issue 13, real samples): non-background masks of one view whose pixels have IoU >= this
    are one mask (Grounded SAM returned the same mask twice; ``segmentation.duplicates``). Copies
    that are all leaves start the grouping as one group, which counts as one mask of its view (a
    ``MergeStep`` of stage ``"duplicate"``, score = IoU); a leaf copy of a parent that contains
    the parent's children is no candidate (the pipeline clears its ``is_leaf``). Measured:
    sample_seq1's clamp, emitted twice in 7 of 8 views (IoU 0.98-0.99), was two instances and all
    20 disagreeing leaf pairs (now one instance; leaf-pair F1 0.959 -> 0.964); sample_seq4's
    mustard-and-banana mask emitted 2-3 times per view left childless copies that grouped as an
    extra object (F1 0.895 -> 0.897); masks of different extent (a can and the can plus a knife
    handle) measured 0.875-0.891. The generated candidates have no copies (no pair on the quick
    suite, AP unchanged); with copies injected (``benchmarks/bench_duplicates.py``, held-out seeds
    0-1) AP 25.6 without the rule, 39.0 with it, 38.6 without copies. 0 = off (the paper's text:
    every leaf is its own candidate)."""
    substitute_stranded_parents: bool = True
    """Ours (issue 13, fix of a fragile spot): with background masks excluded, a non-background
    mask whose every descendant is background (e.g. an object mask whose only child is a blob
    on the table or a part without depth) is on no candidate's path and would never be grouped
    or substituted. True substitutes it in the first substitution round (``Substitution`` with
    no replaced node), so it is regrouped like any substituted parent. Needs ``substitution``.
    No effect without background masks. False = the behaviour before the fix (trace v1)."""


@dataclass(frozen=True, eq=False)
class NodeTable:
    """Every mask of every tree, in canonical order (frame, then mask id).

    Attributes:
        frame: (U,) int32 frame of the node's view.
        view: (U,) int32 index of that view among the initial views (0..V-1).
        mask_id: (U,) int32 mask id within the view.
        parent: (U,) int32 node index of the tree parent, -1 for roots.
        is_leaf: (U,) bool: the node has no child in its tree (proper-segment candidate).
        background: (U,) bool: the mask lies mostly on the support surface; never grouped.
    """

    frame: np.ndarray
    view: np.ndarray
    mask_id: np.ndarray
    parent: np.ndarray
    is_leaf: np.ndarray
    background: np.ndarray

    def __post_init__(self) -> None:
        u = len(self.frame)
        for name in ("view", "mask_id", "parent", "is_leaf", "background"):
            if getattr(self, name).shape != (u,):
                raise SceneError(f"NodeTable.{name} must have shape ({u},)")

    def __len__(self) -> int:
        return len(self.frame)

    def key(self, i: int) -> tuple[int, int]:
        return int(self.frame[i]), int(self.mask_id[i])

    def descendant_leaves(self) -> list[np.ndarray]:
        """For every node, the node indices of the leaves in its subtree (itself for a leaf)."""
        return subtree_leaves(self.parent, self.is_leaf)


@dataclass(frozen=True, eq=False)
class SimilarityGraph:
    """Leaf-graph edge weights over all nodes (Algorithm 1, ConstructLeafGraph).

    Attributes:
        s_spatial: (U, U) float32 S_spatial (eq. 2); NaN where there is no edge (same view).
        s_semantic: (U, U) float32 S_semantic (eq. 3); NaN where there is no edge.
    """

    s_spatial: np.ndarray
    s_semantic: np.ndarray


@dataclass(frozen=True)
class MergeStep:
    """One GroupAndRewire call: groups ``a`` and ``b`` (node indices) became one group."""

    stage: str
    round: int
    a: tuple[int, ...]
    b: tuple[int, ...]
    score: float
    """The mean-linkage similarity of the stage that chose the merge."""
    spatial: float
    semantic: float


@dataclass(frozen=True)
class Substitution:
    """Residual leaves replaced by their tree parent (Sec. III-B.3)."""

    round: int
    parent: int
    replaced: tuple[int, ...]


@dataclass(frozen=True, eq=False)
class GroupingResult:
    """Final groups and every step that produced them.

    ``stops``, ``blocked`` and ``residuals`` explain decisions not taken; they are None in
    traces written before they were recorded.
    """

    groups: tuple[tuple[int, ...], ...]
    merges: tuple[MergeStep, ...]
    substitutions: tuple[Substitution, ...]
    events: tuple[tuple[str, int], ...] = field(default=())
    """Order of all steps: ("merge", i) or ("substitution", j) indices into the two lists."""
    stops: tuple[StageStop, ...] | None = None
    blocked: BlockedPairs | None = None
    residuals: ResidualNotes | None = None


def spatial_similarity(occupancy: np.ndarray, weights: np.ndarray, eps: float = 1e-9) -> np.ndarray:
    """(U, U) weighted Jaccard of occupancy rows (eq. 2).

    occupancy: (U, K) o_i(k) in [0, 1]; weights: (K,) w_hat_k. Returns float32.
    Occupancy rows are sparse (a mask touches a few hundred of tens of thousands of
    super-voxels), so the intersection sum_k w_k min(o_i, o_j) of row i is taken over
    the non-zero columns of row i only (min is 0 elsewhere), and the union follows from
    max(a, b) = a + b - min(a, b): union_ij = W_i + W_j - inter_ij with W_i = sum_k w_k o_i(k).
    Sums are in float64; the result equals the dense float32 formula to float32 round-off.
    """
    occ = np.asarray(occupancy, np.float32)
    u = occ.shape[0]
    w = np.asarray(weights, np.float64)
    rows, cols = np.nonzero(occ)
    vals = occ[rows, cols].astype(np.float64)
    wa = np.bincount(rows, weights=vals * w[cols], minlength=u)  # W_i
    inter = np.zeros((u, u), np.float64)
    starts = np.searchsorted(rows, np.arange(u + 1))  # np.nonzero is row-major: rows sorted
    # One row at a time (a loop over masks, not points): (U, nnz_i) block per row.
    for i in range(u):
        c = cols[starts[i] : starts[i + 1]]
        if len(c):
            inter[i] = np.minimum(occ[:, c], vals[starts[i] : starts[i + 1]]) @ w[c]
    union = wa[:, None] + wa[None, :] - inter
    return (inter / (union + eps)).astype(np.float32)


def semantic_similarity(embeddings: np.ndarray) -> np.ndarray:
    """(U, U) cosine of unit embeddings (eq. 3)."""
    e = np.asarray(embeddings, np.float32)
    return np.clip(e @ e.T, -1.0, 1.0)


class _Groups:
    """Active groups with mean-linkage sums (the state of GroupBySimilarity)."""

    def __init__(self, groups: list[list[int]], s_spat: np.ndarray, s_sem: np.ndarray, view: np.ndarray, n_views: int):
        self.members = [sorted(g) for g in groups]
        self.members.sort(key=lambda g: g[0])
        self.s_spat = np.nan_to_num(s_spat, nan=0.0).astype(np.float64)
        self.s_sem = np.nan_to_num(s_sem, nan=0.0).astype(np.float64)
        self.defined = np.isfinite(s_spat).astype(np.float64)  # leaf pairs that have an edge
        self.view = view
        self.n_views = n_views
        self._rebuild()

    def _rebuild(self) -> None:
        g = len(self.members)
        memb = np.zeros((g, len(self.view)), np.float64)
        views = np.zeros((g, self.n_views), bool)
        for i, m in enumerate(self.members):
            memb[i, m] = 1.0
            views[i, self.view[m]] = True
        self.sum_spat = memb @ self.s_spat @ memb.T
        self.sum_sem = memb @ self.s_sem @ memb.T
        self.count = memb @ self.defined @ memb.T
        self.size = memb.sum(axis=1)
        self.views = views

    def valid(self, one_per_view: bool) -> np.ndarray:
        g = len(self.members)
        ok = ~np.eye(g, dtype=bool)
        if one_per_view:
            ok &= ~self.shared_views()
        else:
            # Algorithm 1's rewiring: w = u + v gets an edge to every neighbour of u or v, so two
            # groups are adjacent iff some member pair has a leaf edge (phi: not within one view)
            ok &= self.count > 0
        return np.triu(ok, 1)

    def shared_views(self) -> np.ndarray:
        vi = self.views.astype(np.int32)
        return (vi @ vi.T) > 0

    def mean(self, which: int, defined_only: bool = True) -> np.ndarray:
        """Mean linkage over the member pairs that have a leaf edge (0 where none has).

        Pairs without an edge (two masks of one view: NaN in the leaf graph) are left out of
        the mean, not counted as 0: with ``one_mask_per_view`` off, a group that holds two
        masks of a view would otherwise see its similarity to that view's masks diluted
        (issue 13). With the rule on, groups never share a view, every member pair has an
        edge and the two means are equal. ``defined_only=False`` divides by all pairs (the
        behaviour before the fix; kept for the tests that show the difference).
        """
        s = self.sum_spat if which == STAGE_SPATIAL else self.sum_sem
        if defined_only:
            return np.divide(s, self.count, out=np.zeros_like(s), where=self.count > 0)
        return s / np.outer(self.size, self.size)

    def merge(self, i: int, j: int) -> None:
        # GroupAndRewire: w = u + v; mean linkage follows from summing rows/cols
        assert i < j
        self.members[i] = sorted(self.members[i] + self.members[j])
        del self.members[j]
        for name in ("sum_spat", "sum_sem", "count"):
            s = getattr(self, name)
            s[i] += s[j]
            s[:, i] += s[:, j]
            s = np.delete(np.delete(s, j, 0), j, 1)
            setattr(self, name, s)
        self.size[i] += self.size[j]
        self.size = np.delete(self.size, j)
        self.views[i] |= self.views[j]
        self.views = np.delete(self.views, j, 0)


def group_nodes(
    groups: list[list[int]],
    sim: SimilarityGraph,
    view: np.ndarray,
    n_views: int,
    cfg: GroupingConfig,
    round_: int = 0,
    record: "list[tuple[StageStop, BlockedPairs]] | None" = None,
) -> tuple[list[list[int]], list[MergeStep]]:
    """GroupBySimilarity (Algorithm 1): stage 1 on S_spatial, then stage 2 on S_semantic.

    ``groups`` is the starting partition (node index lists); returns the final
    partition (sorted by first member) and the merges in order. With ``record`` (a list),
    each stage appends why it stopped (``StageStop`` with ``event`` = merges so far in this
    call, and the pairs a rule blocked); recording never changes the result.
    """
    state = _Groups(groups, sim.s_spatial, sim.s_semantic, view, n_views)
    steps: list[MergeStep] = []
    stages = []
    if cfg.use_spatial:
        stages.append((STAGE_SPATIAL, cfg.tau_spat))
    if cfg.use_semantic:
        stages.append((STAGE_SEMANTIC, cfg.tau_sem))
    for stage, tau in stages:
        while True:
            if len(state.members) <= 1:
                if record is not None:
                    record.append(_record(state, stage, tau, round_, len(steps), None, None))
                break
            valid = view_ok = state.valid(cfg.one_mask_per_view)
            if stage == STAGE_SEMANTIC and cfg.semantic_needs_overlap:
                sp = state.mean(STAGE_SPATIAL)
                valid = valid & (sp > 0.0) & (sp >= cfg.semantic_min_spatial)
            score = np.where(valid, state.mean(stage), -np.inf)
            flat = int(np.argmax(score))  # first maximum in canonical order
            best = score.flat[flat]
            if not np.isfinite(best) or best < tau:
                if record is not None:
                    record.append(_record(state, stage, tau, round_, len(steps), view_ok, valid))
                break
            i, j = divmod(flat, score.shape[1])
            steps.append(
                MergeStep(
                    stage=STAGE_NAMES[stage],
                    round=round_,
                    a=tuple(state.members[i]),
                    b=tuple(state.members[j]),
                    score=float(best),
                    spatial=float(state.mean(STAGE_SPATIAL)[i, j]),
                    semantic=float(state.mean(STAGE_SEMANTIC)[i, j]),
                )
            )
            state.merge(i, j)
    return state.members, steps


def _record(state: _Groups, stage: int, tau: float, round_: int, n_steps: int,
            view_ok: np.ndarray | None, valid: np.ndarray | None) -> tuple[StageStop, BlockedPairs]:
    first = np.array([m[0] for m in state.members], np.int32)
    mean = state.mean(stage) if view_ok is not None else None
    return stop_record(first, STAGE_NAMES[stage], tau, round_, n_steps, mean, view_ok, valid)


def stranded_parents(nodes: NodeTable) -> np.ndarray:
    """Node indices of the non-background masks all of whose descendants are background.

    Such a mask (an object whose only child is a blob on the table, or a part without depth)
    lies on no candidate's root-to-leaf path: its leaves never group, so it would never be
    substituted either (``GroupingConfig.substitute_stranded_parents``).
    """
    bg = np.asarray(nodes.background, bool)
    # for every node, the non-background nodes of its subtree (itself included when not background)
    below = subtree_leaves(nodes.parent, ~bg)
    # a non-leaf without children is a copy of a parent (``segmentation.duplicates``), not stranded
    has_child = np.zeros(len(nodes), bool)
    has_child[nodes.parent[nodes.parent >= 0]] = True
    return np.array([i for i in range(len(nodes))
                     if not bg[i] and not nodes.is_leaf[i] and has_child[i] and len(below[i]) == 1], np.int64)


def substitute_residuals(
    groups: list[list[int]], nodes: NodeTable, round_: int, notes: "list[ResidualNotes] | None" = None,
    stranded: bool = False,
) -> tuple[list[list[int]], list[Substitution]]:
    """Residual-node parent substitution (Sec. III-B.3).

    A residual is a node left alone in its group. A residual is replaced by its tree
    parent only when every leaf below that parent is residual (so at most one proper
    segment stays on each root-to-leaf path); all of those residual leaves make way
    for the one parent node. Background parents are never substituted in. With ``notes`` (a
    list), appends why each residual that stays was not substituted (record only).
    With ``stranded``, ``stranded_parents`` not yet in a group are substituted too (replacing
    nothing: their leaves are background and were never grouped).
    """
    residual = {g[0] for g in groups if len(g) == 1}
    desc = nodes.descendant_leaves()
    subs: list[Substitution] = []
    used_parents: set[int] = set()
    replaced: set[int] = set()
    for r in sorted(residual):
        p = int(nodes.parent[r])
        if p < 0 or p in used_parents or nodes.background[p]:
            continue
        below = [int(x) for x in desc[p] if not nodes.background[x]]
        # the leaves under p may themselves have been substituted in an earlier round: then
        # the node standing for them is the residual one (its subtree root), checked via membership
        if below and all(x in residual or _stands_in(x, residual, nodes) for x in below):
            gone = tuple(sorted(x for x in residual if _in_subtree(x, p, nodes)))
            subs.append(Substitution(round=round_, parent=p, replaced=gone))
            used_parents.add(p)
            replaced.update(gone)
    if stranded:
        grouped = {x for g in groups for x in g}
        for p in stranded_parents(nodes):
            # one node per root-to-leaf path: not when p or an ancestor of p is already in use
            taken = grouped | used_parents
            if not any(_in_subtree(int(p), t, nodes) for t in taken):
                subs.append(Substitution(round=round_, parent=int(p), replaced=()))
                used_parents.add(int(p))
    if notes is not None:
        notes.append(_residual_notes(residual, replaced, used_parents, desc, nodes, round_))
    if not subs:
        return groups, subs
    new = [g for g in groups if not (len(g) == 1 and g[0] in replaced)]
    new += [[s.parent] for s in subs]
    new.sort(key=lambda g: g[0])
    return new, subs


def _residual_notes(residual: set[int], replaced: set[int], used: set[int], desc: list[np.ndarray],
                    nodes: NodeTable, round_: int) -> ResidualNotes:
    """Why each residual in ``residual - replaced`` kept its place (the tests of substitute_residuals)."""
    rows = []
    for r in sorted(residual - replaced):
        p = int(nodes.parent[r])
        if p < 0:
            rows.append((r, 1, -1))
        elif nodes.background[p]:
            rows.append((r, 2, p))
        elif p in used:
            rows.append((r, 4, p))
        else:
            below = [int(x) for x in desc[p] if not nodes.background[x]]
            other = next((x for x in below if not (x in residual or _stands_in(x, residual, nodes))), -1)
            rows.append((r, 3, other))
    a = np.array(rows, np.int64).reshape(-1, 3)
    return ResidualNotes(a[:, 0].astype(np.int32), np.full(len(a), round_, np.int32), a[:, 1].astype(np.int8),
                         a[:, 2].astype(np.int32))


def _in_subtree(x: int, root: int, nodes: NodeTable) -> bool:
    j = x
    while j >= 0:
        if j == root:
            return True
        j = int(nodes.parent[j])
    return False


def _stands_in(leaf: int, residual: set[int], nodes: NodeTable) -> bool:
    """True if an ancestor of ``leaf`` (from an earlier substitution) is a residual node."""
    j = int(nodes.parent[leaf])
    while j >= 0:
        if j in residual:
            return True
        j = int(nodes.parent[j])
    return False


def run_grouping(nodes: NodeTable, sim: SimilarityGraph, n_views: int, cfg: GroupingConfig,
                 duplicates: "tuple[DuplicatePair, ...]" = (),
                 overlaps: "list[np.ndarray] | tuple[np.ndarray, ...] | None" = None) -> GroupingResult:
    """Algorithm 1 plus substitution and regrouping. Background nodes never take part.

    ``duplicates`` (``Duplicates.pairs`` of ``segmentation.duplicates.duplicate_masks``, ours): pairs of leaves of one
    view that are the same candidate; each connected set starts as one group (recorded as
    ``"duplicate"`` merges before stage 1). Ignored when ``cfg.duplicate_iou`` is 0.
    ``overlaps``: per view, the (M_v, M_v) pixel intersection counts of its nodes in node order
    (diagonal = areas; ``trees.build_tree_overlaps``); read only by the reunion's containment gate.
    """
    start = [[int(i)] for i in np.flatnonzero(nodes.is_leaf & ~nodes.background)]
    first: list[MergeStep] = []
    if cfg.duplicate_iou > 0 and duplicates:
        start, first = _join_duplicates(start, duplicates, nodes)
    stops: list[StageStop] = []
    blocked: list[BlockedPairs] = []
    notes: list[ResidualNotes] = []

    def keep(rec: list[tuple[StageStop, BlockedPairs]], offset: int) -> None:
        # event counts and stop indices of this call become global ones
        for stop, bp in rec:
            stops.append(replace(stop, event=stop.event + offset))
            blocked.append(replace(bp, stop=np.full(len(bp.a), len(stops) - 1, np.int32)))

    rec: list[tuple[StageStop, BlockedPairs]] = []
    groups, merges = group_nodes(start, sim, nodes.view, n_views, cfg, round_=0, record=rec)
    keep(rec, len(first))
    merges = first + merges
    events: list[tuple[str, int]] = [("merge", i) for i in range(len(merges))]
    subs_all: list[Substitution] = []
    if cfg.substitution:
        for rnd in range(1, cfg.substitution_rounds + 1):
            groups, subs = substitute_residuals(groups, nodes, rnd, notes=notes,
                                                stranded=cfg.substitute_stranded_parents)
            if not subs:
                break
            events += [("substitution", len(subs_all) + k) for k in range(len(subs))]
            subs_all += subs
            rec = []
            offset = len(events)
            groups, more = group_nodes(groups, sim, nodes.view, n_views, cfg, round_=rnd, record=rec)
            keep(rec, offset)
            events += [("merge", len(merges) + k) for k in range(len(more))]
            merges += more
    if cfg.reunion_tau > 0:
        contain = (same_view_containment(nodes.view, overlaps)
                   if overlaps is not None and cfg.reunion_max_contain < 1 else None)
        groups, more = reunite_split_groups(groups, sim, nodes.view, n_views, cfg.reunion_tau,
                                             cfg.substitution_rounds + 1, contain, cfg.reunion_max_contain,
                                             cfg.reunion_min_semantic)
        events += [("merge", len(merges) + k) for k in range(len(more))]
        merges += more
    return GroupingResult(
        groups=tuple(tuple(g) for g in groups),
        merges=tuple(merges),
        substitutions=tuple(subs_all),
        events=tuple(events),
        stops=tuple(stops),
        blocked=BlockedPairs.concat(blocked),
        residuals=ResidualNotes(*(np.concatenate([getattr(n, f) for n in notes]) if notes else np.zeros(0, dt)
                                  for f, dt in (("node", np.int32), ("round", np.int32), ("reason", np.int8),
                                                ("other", np.int32)))),
    )


def _join_duplicates(start: list[list[int]], pairs, nodes: NodeTable) -> tuple[list[list[int]], list[MergeStep]]:
    """Start groups with each set of duplicate leaves joined, and one ``"duplicate"`` merge per join
    (pairs in canonical order; a pair whose nodes are not both starting leaves is skipped)."""
    members = {g[0]: [g[0]] for g in start}
    root = {g[0]: g[0] for g in start}
    steps: list[MergeStep] = []
    for p in sorted(pairs, key=lambda q: (q.a, q.b)):
        if p.a not in root or p.b not in root or nodes.view[p.a] != nodes.view[p.b]:
            continue
        ra, rb = root[p.a], root[p.b]
        if ra == rb:
            continue
        ra, rb = min(ra, rb), max(ra, rb)
        steps.append(MergeStep(stage="duplicate", round=0, a=tuple(members[ra]), b=tuple(members[rb]),
                               score=float(p.iou), spatial=0.0, semantic=0.0))  # same view: no edge
        members[ra] = sorted(members[ra] + members[rb])
        for x in members.pop(rb):
            root[x] = ra
    groups = [members[r] for r in sorted(members)]
    return groups, steps


def same_view_containment(view: np.ndarray, overlaps) -> np.ndarray:
    """(U, U) float32: for two nodes of one view, their pixel intersection over the smaller
    mask's area (0 for nodes of different views, and on the diagonal)."""
    view = np.asarray(view)
    out = np.zeros((len(view), len(view)), np.float32)
    for v, inter in enumerate(overlaps):
        idx = np.flatnonzero(view == v)
        if inter.shape != (len(idx), len(idx)):
            raise SceneError(f"view {v}: overlaps of shape {inter.shape} for {len(idx)} nodes")
        area = np.diag(inter).astype(np.float64)
        c = inter / np.maximum(np.minimum(area[:, None], area[None, :]), 1.0)
        np.fill_diagonal(c, 0.0)
        out[np.ix_(idx, idx)] = c
    return out


def reunion_weights(merges: "tuple[MergeStep, ...] | list[MergeStep]", view: np.ndarray) -> np.ndarray:
    """(U,) float64 confidence weight of every node: 0 for the masks of a reunion's second group
    (``MergeStep.b``) in views its first group already held, 1 otherwise, so that a reunited
    group counts each view once for them (ours, ``supervoxel_vote``'s ``mask_weight``)."""
    view = np.asarray(view)
    w = np.ones(len(view), np.float64)
    for m in merges:
        if m.stage == "reunion":
            held = set(view[list(m.a)].tolist())
            b = np.asarray(m.b, np.int64)
            w[b[np.isin(view[b], list(held))]] = 0.0
    return w


def reunite_split_groups(
    groups: list[list[int]], sim: SimilarityGraph, view: np.ndarray, n_views: int, tau: float, round_: int,
    contain: np.ndarray | None = None, max_contain: float = 1.0, min_semantic: float = -1.0,
) -> tuple[list[list[int]], list[MergeStep]]:
    """Merge groups of one object that the one-mask-per-view rule kept apart (ours).

    Only groups of two or more masks that share at least one view are candidates; their
    similarity is the mean S_spatial over their cross-view pairs (same-view pairs have no
    edge). Greedy, best pair first, as stage 1. ``contain`` ((U, U), ``same_view_containment``):
    a pair whose masks of a shared view have containment >= ``max_contain`` is not a candidate
    (one mask holds the other: a mask spanning the object and a neighbour, not a second part);
    nor is one whose mean S_semantic over cross-view pairs is under ``min_semantic``.
    """
    state = _Groups(groups, sim.s_spatial, sim.s_semantic, view, n_views)
    steps: list[MergeStep] = []
    while len(state.members) > 1:
        big = state.size >= 2
        ok = np.triu(state.shared_views() & big[:, None] & big[None, :] & (state.count > 0), 1)
        if min_semantic > -1:
            ok &= state.mean(STAGE_SEMANTIC, defined_only=True) >= min_semantic
        if contain is not None:
            for i, j in zip(*np.nonzero(ok)):
                if contain[np.ix_(state.members[i], state.members[j])].max() >= max_contain:
                    ok[i, j] = False
        mean_sp = state.mean(STAGE_SPATIAL, defined_only=True)
        score = np.where(ok, mean_sp, -np.inf)
        flat = int(np.argmax(score))
        best = score.flat[flat]
        if not np.isfinite(best) or best < tau:
            break
        i, j = divmod(flat, score.shape[1])
        steps.append(MergeStep(stage="reunion", round=round_, a=tuple(state.members[i]), b=tuple(state.members[j]),
                               score=float(best), spatial=float(mean_sp[i, j]),
                               semantic=float(state.mean(STAGE_SEMANTIC, defined_only=True)[i, j])))
        state.merge(i, j)
    return state.members, steps
