"""What the grouping records about decisions it did not take (for ``clutt3r_core.explain``).

Kept apart from ``grouping.py`` (which stays about the algorithm): the types of the records
and the one pure function that fills a stage stop's record. Recording never changes a
result: ``group_nodes`` computes the same partition with or without it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["BLOCK_RULES", "RESIDUAL_REASONS", "StageStop", "BlockedPairs", "ResidualNotes", "stop_record"]

BLOCK_RULES = ("none", "one_mask_per_view", "overlap_gate")
"""Codes of ``BlockedPairs.rule``: the rule that kept a pair whose score was >= tau out of the merge."""
RULE_VIEW, RULE_GATE = 1, 2

RESIDUAL_REASONS = ("substituted", "root", "parent_background", "sibling_grouped", "parent_taken")
"""Codes of ``ResidualNotes.reason``: why a residual leaf was not replaced by its tree parent."""


@dataclass(frozen=True)
class StageStop:
    """Why one stage of one round stopped merging (recorded for explanations, not used by the algorithm).

    ``event`` is the number of events (``GroupingResult.events``) done when it stopped, so
    ``Trace.groups_at(event)`` are the groups it left. ``best_score`` is the best score among
    the pairs the rules allowed (NaN when no pair was left), below ``tau``; ``best_a``/``best_b``
    are the first members of that pair (-1 = none). ``blocked_score`` is the best score among
    pairs a rule excluded (NaN = none), ``blocked_rule`` that rule (``BLOCK_RULES``).
    """

    stage: str
    round: int
    event: int
    n_groups: int
    tau: float
    best_score: float
    best_a: int
    best_b: int
    blocked_score: float
    blocked_rule: str


@dataclass(frozen=True, eq=False)
class BlockedPairs:
    """Group pairs that a rule kept apart although their score reached the stage's tau.

    Recorded at each stage stop (``stop`` indexes ``GroupingResult.stops``): the groups
    are those of ``Trace.groups_at(stops[stop].event)``, named by their first member
    (node index). Only pairs with score >= tau are kept: every other pair was also kept
    apart by the threshold, which ``explain_pair`` recomputes from the leaf graph.

    Attributes:
        stop: (P,) int32 index into the stops.
        a, b: (P,) int32 first members of the two groups (a < b).
        rule: (P,) int8 ``BLOCK_RULES`` code.
        score: (P,) float32 the stage's mean-linkage score of the pair (unitless, in [-1, 1]).
    """

    stop: np.ndarray
    a: np.ndarray
    b: np.ndarray
    rule: np.ndarray
    score: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.stop)
        for name in ("a", "b", "rule", "score"):
            if getattr(self, name).shape != (n,):
                raise SceneError(f"BlockedPairs.{name} must have shape ({n},)")

    @staticmethod
    def concat(parts: list["BlockedPairs"]) -> "BlockedPairs":
        cat = lambda name, dt: np.concatenate([getattr(p, name) for p in parts]).astype(dt) if parts \
            else np.zeros(0, dt)  # noqa: E731
        return BlockedPairs(cat("stop", np.int32), cat("a", np.int32), cat("b", np.int32), cat("rule", np.int8),
                            cat("score", np.float32))


@dataclass(frozen=True, eq=False)
class ResidualNotes:
    """Every residual (a leaf alone in its group) the substitution examined and kept.

    Attributes:
        node: (R,) int32 the residual leaf.
        round: (R,) int32 substitution round.
        reason: (R,) int8 ``RESIDUAL_REASONS`` code (never 0: substituted leaves are in ``substitutions``).
        other: (R,) int32 the parent (``parent_background``, ``parent_taken``) or the grouped
            leaf under the parent (``sibling_grouped``); -1 for ``root``.
    """

    node: np.ndarray
    round: np.ndarray
    reason: np.ndarray
    other: np.ndarray

    def __post_init__(self) -> None:
        n = len(self.node)
        for name in ("round", "reason", "other"):
            if getattr(self, name).shape != (n,):
                raise SceneError(f"ResidualNotes.{name} must have shape ({n},)")


def stop_record(first: np.ndarray, stage: str, tau: float, round_: int, n_steps: int, mean: np.ndarray | None,
                view_ok: np.ndarray | None, valid: np.ndarray | None) -> tuple[StageStop, BlockedPairs]:
    """Why a stage stopped: its best allowed score and the pairs >= tau that a rule excluded.

    first: (G,) first member of each group; mean: (G, G) the stage's mean linkage; view_ok:
    (G, G) bool upper-triangular pairs the one-mask-per-view rule allows; valid: (G, G) bool
    pairs every rule allows. None (one group left): a stop with no pair.
    """
    none = BlockedPairs(*(np.zeros(0, dt) for dt in (np.int32, np.int32, np.int32, np.int8, np.float32)))
    if view_ok is None or valid is None or mean is None:
        return StageStop(stage, round_, n_steps, len(first), float(tau), float("nan"), -1, -1,
                         float("nan"), BLOCK_RULES[0]), none
    pair = np.triu(np.ones(mean.shape, bool), 1)
    rule = np.zeros(mean.shape, np.int8)
    rule[pair & ~view_ok] = RULE_VIEW
    rule[pair & view_ok & ~valid] = RULE_GATE
    allowed = np.where(valid, mean, -np.inf)
    flat = int(np.argmax(allowed))
    best = float(allowed.flat[flat])
    bi, bj = divmod(flat, mean.shape[1])
    blocked = np.where(rule > 0, mean, -np.inf)
    bflat = int(np.argmax(blocked))
    bbest = float(blocked.flat[bflat])
    stop = StageStop(
        stage=stage, round=round_, event=n_steps, n_groups=len(first), tau=float(tau),
        best_score=best if np.isfinite(best) else float("nan"),
        best_a=int(first[bi]) if np.isfinite(best) else -1, best_b=int(first[bj]) if np.isfinite(best) else -1,
        blocked_score=bbest if np.isfinite(bbest) else float("nan"),
        blocked_rule=BLOCK_RULES[int(rule.flat[bflat])] if np.isfinite(bbest) else BLOCK_RULES[0],
    )
    ii, jj = np.nonzero((rule > 0) & (mean >= tau))
    return stop, BlockedPairs(np.zeros(len(ii), np.int32), first[ii], first[jj], rule[ii, jj],
                              mean[ii, jj].astype(np.float32))
