"""Why two masks were not put together, and why a super-voxel went where it did.

``explain_pair(run, a, b)`` follows two masks through the grouping's events (the groups
each was in at every step), checks at every stage stop what kept their groups apart (the
one-mask-per-view rule, the stage-2 overlap gate, or a mean-linkage score below the
stage's tau; Algorithm 1, Sec. III-B.2) and names the first one, the step where their fates
diverged, and their final instances. ``explain_supervoxel(run, k)`` gives the super-voxel's
votes per group (Sec. III-B.4), the winner's coverage, and the rule that decided.

Everything is read from the trace (``segmentation/trace.py``); the only arithmetic is the
mean linkage of two groups (mean of the leaf-pair similarities that have an edge, exactly as the
grouping computes it) on the recorded leaf graph. Traces written before stage stops and
vote reasons were recorded still load: their explanations say "not recorded in this run".
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Union

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.grouping import BLOCK_RULES, RESIDUAL_REASONS
from clutt3r_core.segmentation.trace import Trace
from clutt3r_core.segmentation.vote import VOTE_REASONS

__all__ = ["GroupAt", "StageCheck", "PairExplanation", "GroupVote", "SupervoxelExplanation",
           "explain_pair", "explain_supervoxel", "resolve_mask", "as_trace", "RULE_TEXT", "group_history"]

MaskRef = Union[int, tuple[int, int]]
"""A node index into ``trace.nodes``, or (frame, mask id)."""

RULE_TEXT = {
    "merged": "merged into one group",
    "same_view": "both masks are of one view: the leaf graph has no edge between them",
    "background": "a mask lies on the support surface and never takes part in the grouping",
    "not_grouped": "a parent mask that never entered the grouping (its residual leaves were not substituted)",
    "copy_of_parent": "a childless copy of a parent mask of its view (pixel IoU >= grouping.duplicate_iou): "
                      "no candidate (segmentation/duplicates.py)",
    "one_mask_per_view": "their groups share a view (one mask per view per group)",
    "overlap_gate": "stage-2 overlap gate: their groups share no super-voxel, or only a sliver (mean S_spatial 0 or "
                    "under grouping.semantic_min_spatial)",
    "below_tau_spat": "mean S_spatial of their groups below tau_spat",
    "below_tau_sem": "mean S_semantic of their groups below tau_sem",
    "group_dropped": "their group is not an instance (vote filters)",
    "not_recorded": "why the stages stopped is not recorded in this run (re-run clutt3r segment to record it)",
}
"""Every rule an explanation can name, in words."""


def as_trace(run) -> Trace:
    """A ``Trace`` from a trace, a ``Segmentation`` (``.trace``) or a run folder path."""
    if isinstance(run, Trace):
        return run
    if hasattr(run, "trace") and isinstance(run.trace, Trace):
        return run.trace
    if isinstance(run, (str, Path)):
        from clutt3r_core.segmentation.trace import load_trace

        p = Path(run)
        return load_trace(p / "trace" if (p / "trace").is_dir() else p)
    raise TypeError(f"run must be a Trace, a Segmentation or a run folder, got {type(run).__name__}")


def resolve_mask(trace: Trace, ref: MaskRef) -> int:
    """Node index of ``ref`` (a node index, or (frame, mask id)); SceneError naming what is missing."""
    n = trace.nodes
    if isinstance(ref, (tuple, list)):
        f, m = int(ref[0]), int(ref[1])
        hit = np.flatnonzero((n.frame == f) & (n.mask_id == m))
        if len(hit) == 0:
            dropped = [t for t in trace.trees if t.frame == f and m in set(t.dropped_ids.tolist())]
            if dropped:
                raise SceneError(f"mask {f}:{m} was dropped when building frame {f}'s tree (too small or a duplicate)")
            frames = sorted(set(n.frame.tolist()))
            raise SceneError(f"no mask {f}:{m} in this run (frames {frames})")
        return int(hit[0])
    i = int(ref)
    if not 0 <= i < len(n):
        raise SceneError(f"node {i} out of range 0..{len(n) - 1}")
    return i


@dataclass(frozen=True)
class GroupAt:
    """From replay step ``step`` on (events done), the mask's group (node indices; () = in no group)."""

    step: int
    group: tuple[int, ...]


@dataclass(frozen=True)
class StageCheck:
    """The two masks' groups when one stage of one round stopped.

    ``spatial``/``semantic`` are the mean linkage of the two groups (unitless, NaN when a
    mask is in no group), ``score``/``tau`` the stopping stage's, ``rule`` a ``RULE_TEXT``
    key; ``recorded`` is True when the trace's blocked pairs list this pair (rules only).
    """

    stage: str
    round: int
    step: int
    rule: str
    spatial: float
    semantic: float
    score: float
    tau: float
    shared_views: tuple[int, ...]
    recorded: bool
    also: tuple[str, ...] = ()
    """Rules that also applied but did not decide (the score was below tau anyway)."""


@dataclass(frozen=True)
class PairExplanation:
    """Why masks ``a`` and ``b`` (node indices) ended together or apart.

    ``s_spatial``/``s_semantic``: their leaf-graph similarities (NaN = no edge);
    ``tau_spat``/``tau_sem``: the run's thresholds; ``history_a/b``: change points of their
    groups; ``checks``: one per stage stop; ``rule``: the first rule or score that kept them
    apart (``"merged"`` when merged); ``final_rule``: the rule at the last stop;
    ``diverge_step``: the replay step where their fates diverged (the merge, the merge after
    which their groups shared a view, or the last stop that left them apart);
    ``merge_event``: index into ``grouping.events`` of their merge, -1 = never.
    """

    a: int
    b: int
    key_a: tuple[int, int]
    key_b: tuple[int, int]
    s_spatial: float
    s_semantic: float
    tau_spat: float
    tau_sem: float
    history_a: tuple[GroupAt, ...]
    history_b: tuple[GroupAt, ...]
    checks: tuple[StageCheck, ...]
    together: bool
    rule: str
    final_rule: str
    merge_event: int
    diverge_step: int
    instance_a: int
    instance_b: int
    recorded: bool
    note: str = ""

    def to_json(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        fa, fb = (f"{k[0]}:{k[1]}" for k in (self.key_a, self.key_b))
        lines = [f"masks {fa} (node {self.a}) and {fb} (node {self.b}): "
                 + ("TOGETHER" if self.together else "APART")
                 + f"; final instances {_inst(self.instance_a)} and {_inst(self.instance_b)}",
                 f"leaf pair: S_spatial {_f(self.s_spatial)} (tau_spat {self.tau_spat:.2f}), "
                 f"S_semantic {_f(self.s_semantic)} (tau_sem {self.tau_sem:.2f})"]
        if self.together:
            lines.append(f"merged at event {self.merge_event} (replay step {self.diverge_step})")
        else:
            lines.append(f"first kept apart by: {self.rule} - {RULE_TEXT.get(self.rule, self.rule)}")
            if self.final_rule != self.rule:
                lines.append(f"at the last stop: {self.final_rule} - {RULE_TEXT.get(self.final_rule, self.final_rule)}")
            lines.append(f"fates diverged at replay step {self.diverge_step}")
        for c in self.checks:
            tail = "" if c.rule == "merged" else f", {c.stage} score {_f(c.score)} vs tau {c.tau:.2f}"
            views = f", shared views {list(c.shared_views)}" if c.shared_views else ""
            views += f"; also {', '.join(c.also)}" if c.also else ""
            lines.append(f"  {c.stage} stage, round {c.round}, stopped at step {c.step}: {c.rule} "
                         f"(groups' mean S_spatial {_f(c.spatial)}, S_semantic {_f(c.semantic)}{tail}{views})")
        for name, h in (("a", self.history_a), ("b", self.history_b)):
            lines.append(f"groups of {name}: " + "; ".join(f"step {g.step}: {len(g.group)} masks" if g.group
                                                           else f"step {g.step}: none" for g in h))
        if self.note:
            lines.append(self.note)
        return "\n".join(lines)


def _f(x: float) -> str:
    return "n/a" if not np.isfinite(x) else f"{x:.3f}"


def _inst(i: int) -> str:
    return "none" if i < 0 else str(i)


def group_history(trace: Trace, nodes: list[int]) -> list[list[GroupAt]]:
    """For each node, the change points of its group over the replay steps 0..len(events).

    A residual leaf replaced by its parent (substitution) follows the parent from then on;
    a non-leaf node is in no group until it is substituted in.
    """
    g = trace.grouping
    member: dict[int, tuple[int, ...]] = {int(i): (int(i),) for i in
                                          np.flatnonzero(trace.nodes.is_leaf & ~trace.nodes.background)}
    stand = {x: x for x in nodes}
    out: list[list[GroupAt]] = [[GroupAt(0, member.get(x, ()))] for x in nodes]
    for step, (kind, idx) in enumerate(g.events, start=1):
        if kind == "merge":
            m = g.merges[idx]
            new = tuple(sorted(m.a + m.b))
            for x in new:
                member[x] = new
        else:
            s = g.substitutions[idx]
            for r in s.replaced:
                member.pop(r, None)
                for x, st in stand.items():
                    if st == r:
                        stand[x] = s.parent
            member[s.parent] = (s.parent,)
        for h, x in zip(out, nodes):
            cur = member.get(stand[x], ())
            if cur != h[-1].group:
                h.append(GroupAt(step, cur))
    return out


def _at(h: list[GroupAt] | tuple[GroupAt, ...], step: int) -> tuple[int, ...]:
    cur: tuple[int, ...] = ()
    for g in h:
        if g.step > step:
            break
        cur = g.group
    return cur


def _linkage(trace: Trace, ga: tuple[int, ...], gb: tuple[int, ...]) -> tuple[float, float]:
    """Mean linkage of two groups, as ``grouping._Groups.mean``: over the member pairs that have
    a leaf edge (same-view pairs, NaN in the leaf graph, are left out; 0 when no pair has one)."""
    if not ga or not gb:
        return float("nan"), float("nan")
    ix = np.ix_(list(ga), list(gb))
    n = max(int(np.isfinite(trace.s_spatial[ix]).sum()), 1)
    sp = float(np.nansum(trace.s_spatial[ix].astype(np.float64)) / n)
    se = float(np.nansum(trace.s_semantic[ix].astype(np.float64)) / n)
    return sp, se


def explain_pair(run, a: MaskRef, b: MaskRef) -> PairExplanation:
    """Why masks ``a`` and ``b`` (node indices or (frame, mask id)) ended together or apart."""
    t = as_trace(run)
    ia, ib = resolve_mask(t, a), resolve_mask(t, b)
    if ia == ib:
        raise SceneError(f"pick two different masks (both are {t.nodes.key(ia)})")
    n, g, cfg = t.nodes, t.grouping, t.config.grouping
    ha, hb = group_history(t, [ia, ib])
    inst = t.node_instance(follow_substitutions=True)
    end = len(g.events)
    views = n.view
    stops = g.stops
    recorded = stops is not None and g.blocked is not None
    bset: dict[tuple[int, int, int], int] = {}
    if recorded and len(g.blocked.a):
        for s_, x, y, r in zip(g.blocked.stop.tolist(), g.blocked.a.tolist(), g.blocked.b.tolist(),
                               g.blocked.rule.tolist()):
            bset[(s_, x, y)] = r

    # the merge that put them together, if any
    merge_step = next((s for s in range(end + 1) if _at(ha, s) and _at(ha, s) == _at(hb, s)), -1)
    checks: list[StageCheck] = []
    for si, st in enumerate(stops or ()):
        ga, gb = _at(ha, st.event), _at(hb, st.event)
        sp, se = _linkage(t, ga, gb)
        shared = tuple(sorted(set(views[list(ga)].tolist()) & set(views[list(gb)].tolist()))) if ga and gb else ()
        score = sp if st.stage in ("spatial", "reunion") else se
        rec, also = False, ()
        if ga and ga == gb:
            rule = "merged"
        elif not ga or not gb:
            rule = _absent_rule(t, ia if not ga else ib)
        else:
            rule, also, rec = _stop_rule(st, cfg, ga, gb, shared, sp, score, si, bset)
        checks.append(StageCheck(st.stage, st.round, st.event, rule, sp, se, score, st.tau, shared, rec, also))

    s_sp, s_se = float(t.s_spatial[ia, ib]), float(t.s_semantic[ia, ib])
    together = merge_step >= 0
    note = ""
    if together:
        rule = final = "merged"
        diverge = merge_step
        if inst[ia] < 0:
            rule = final = "group_dropped"
            note = "merged, but " + _dropped_text(t, _at(ha, end))
    else:
        apart = [c for c in checks if c.rule != "merged"]
        if views[ia] == views[ib] and not n.background[ia] and not n.background[ib]:
            rule = "same_view"
        elif not _at(ha, 0) or not _at(hb, 0):
            # a parent substituted in later: what kept it apart once it was in play
            rule = next((c.rule for c in apart if c.rule not in ("background", "not_grouped")),
                        _absent_rule(t, ia if not _at(ha, 0) else ib))
        elif apart:
            rule = apart[0].rule
        else:
            rule = "not_recorded"
        final = apart[-1].rule if apart else rule
        diverge = _diverge_step(ha, hb, views, apart, rule)
        if not recorded:
            note = RULE_TEXT["not_recorded"]
    res = g.residuals
    if res is not None:
        for i in (ia, ib):
            for rnd, r, o in zip(res.round[res.node == i].tolist(), res.reason[res.node == i].tolist(),
                                 res.other[res.node == i].tolist()):
                note += (f"\nmask {n.key(i)[0]}:{n.key(i)[1]} was a residual in substitution round {rnd} and "
                         f"stayed: {RESIDUAL_TEXT[RESIDUAL_REASONS[r]]}"
                         + (f" (node {o}, mask {n.key(o)[0]}:{n.key(o)[1]})" if o >= 0 else ""))
    note = note.strip()
    return PairExplanation(
        a=ia, b=ib, key_a=n.key(ia), key_b=n.key(ib), s_spatial=s_sp, s_semantic=s_se,
        tau_spat=float(cfg.tau_spat), tau_sem=float(cfg.tau_sem), history_a=tuple(ha), history_b=tuple(hb),
        checks=tuple(checks), together=together, rule=rule, final_rule=final,
        merge_event=merge_step - 1 if together else -1, diverge_step=int(diverge),
        instance_a=int(inst[ia]), instance_b=int(inst[ib]), recorded=recorded, note=note,
    )


def _stop_rule(st, cfg, ga, gb, shared, sp, score, si, bset) -> tuple[str, tuple[str, ...], bool]:
    """What kept groups ``ga``/``gb`` apart at stop ``st``: (the rule, the other rules that also
    applied, recorded). A rule is named first only when their score reached tau (it changed
    the decision; these pairs are the trace's blocked pairs); otherwise the score is."""
    rules = []
    if shared and (cfg.one_mask_per_view or (len(ga) == 1 and len(gb) == 1)):
        rules.append("one_mask_per_view")
    # the overlap gate: S_spatial must be above 0 and at least ``semantic_min_spatial`` (a config
    # written before the field loads it as 0: ``config.ADDED_AFTER_V1``)
    if st.stage == "semantic" and cfg.semantic_needs_overlap and not (
            sp > 0.0 and sp >= cfg.semantic_min_spatial):
        rules.append("overlap_gate")
    key = (si, min(ga[0], gb[0]), max(ga[0], gb[0]))
    if key in bset:  # recorded: a rule blocked a pair whose score reached tau
        r = BLOCK_RULES[bset[key]]
        return r, tuple(x for x in rules if x != r), True
    if score >= st.tau and rules:  # not in the record (an older trace): the rule decided
        return rules[0], tuple(rules[1:]), False
    return ("below_tau_sem" if st.stage == "semantic" else "below_tau_spat"), tuple(rules), False


def _absent_rule(t: Trace, i: int) -> str:
    n = t.nodes
    if n.background[i]:
        return "background"
    if not n.is_leaf[i] and not (n.parent == i).any():  # no child: a copy whose is_leaf was cleared
        return "copy_of_parent"
    return "not_grouped"


def _diverge_step(ha, hb, views, apart: list[StageCheck], rule: str) -> int:
    """The step from which they could no longer come together: their groups started to share a
    view, else the last stop that left them apart (their last chance)."""
    if rule in ("same_view", "background", "not_grouped"):
        return 0
    steps = sorted({h.step for h in (*ha, *hb)})
    for s in steps:
        ga, gb = _at(ha, s), _at(hb, s)
        if ga and gb and set(views[list(ga)].tolist()) & set(views[list(gb)].tolist()):
            return s
    return apart[-1].step if apart else 0


def _dropped_text(t: Trace, group: tuple[int, ...]) -> str:
    v, cfg = t.vote, t.config.vote
    gi = next((k for k, m in enumerate(t.grouping.groups) if m == group), -1)
    pts = "not recorded" if v.group_points is None or gi < 0 else f"{v.group_points[gi]:.0f}"
    return (f"their group (index {gi}, {len(group)} masks; min_group_size {cfg.min_group_size}) won "
            f"{pts} points (min_instance_points {cfg.min_instance_points}) and is not an instance")


@dataclass(frozen=True)
class GroupVote:
    """One group's vote for a super-voxel: sum of its masks' occupancies (unitless)."""

    group: int
    vote: float
    n_masks: int
    instance: int
    eligible: bool
    """False: fewer than ``min_group_size`` masks, so the group did not vote."""


@dataclass(frozen=True)
class SupervoxelExplanation:
    """Why super-voxel ``k`` has instance ``label`` (-1 = none).

    ``tally``: the top groups by vote (up to three, best first; empty when not recorded);
    ``winner``/``runner_up``: recorded votes; ``coverage``: best single-mask coverage of the
    winner (vs ``min_coverage``); ``reason``: a ``VOTE_REASONS`` name or ``not_recorded``.
    """

    k: int
    label: int
    winner_group: int
    winner_vote: float
    runner_up_vote: float
    coverage: float
    min_coverage: float
    tally: tuple[GroupVote, ...]
    reason: str
    recorded: bool
    winner_points: float
    min_instance_points: int
    span_cleared: tuple[tuple[int, int], ...] = ()
    """(node, its group) of each mask whose occupancy of this super-voxel the vote ignored: it
    spans another group's footprint there (``vote.span_cover``, ``segmentation.span``), or its group is
    not an instance and a spanning mask was cleared there (``vote.span_instances_only``)."""

    def to_json(self) -> dict:
        return asdict(self)

    def text(self) -> str:
        lines = [f"super-voxel {self.k}: " + (f"instance {self.label}" if self.label >= 0 else "unlabelled")
                 + f" ({self.reason}: {_VOTE_TEXT.get(self.reason, self.reason)})"]
        if self.winner_group >= 0:
            lines.append(f"winner group {self.winner_group} with vote {self.winner_vote:.3f}, runner-up vote "
                         f"{self.runner_up_vote:.3f}; winner's best mask covers {self.coverage:.2f} "
                         f"(min_coverage {self.min_coverage:.2f})")
            if self.runner_up_vote >= self.winner_vote > 0:
                lines.append("a tie: the vote went to the group with the lower index (canonical order), "
                             "not to the better one")
        if self.reason == "group_dropped" and np.isfinite(self.winner_points):
            lines.append(f"winner group won {self.winner_points:.0f} points (min_instance_points "
                         f"{self.min_instance_points})")
        for gv in self.tally:
            lines.append(f"  group {gv.group}: vote {gv.vote:.3f} from {gv.n_masks} masks -> instance "
                         f"{_inst(gv.instance)}" + ("" if gv.eligible else " (below min_group_size: no vote)"))
        for node, gi in self.span_cleared:
            lines.append(f"  mask node {node} (group {gi}) did not vote here: it spans another group's footprint "
                         "that its own group's other masks do not cover (vote.span_cover), or its group is not "
                         "an instance and a spanning mask's vote was cleared here (vote.span_instances_only)")
        if not self.recorded:
            lines.append("the full tally and the reason are not recorded in this run")
        return "\n".join(lines)


_VOTE_TEXT = {
    "labelled": "the winning group is an instance and its best mask covers enough of the super-voxel",
    "no_vote": "no group's mask touches it",
    "support": "it lies on the support surface (table, tray), never labelled",
    "coverage": "the winner's best mask covers less than min_coverage of it",
    "group_dropped": "the winning group is not an instance (too few masks or points)",
    "not_recorded": "not recorded in this run",
}


def explain_supervoxel(run, k: int) -> SupervoxelExplanation:
    """The vote of super-voxel ``k`` (index into the run's super-voxels)."""
    t = as_trace(run)
    v, cfg = t.vote, t.config.vote
    nk = len(v.sv_label)
    k = int(k)
    if not 0 <= k < nk:
        raise SceneError(f"super-voxel {k} out of range 0..{nk - 1}")
    group_inst = np.full(len(t.grouping.groups), -1, np.int64)
    group_inst[v.instance_group] = np.arange(len(v.instance_group))
    sizes = [len(m) for m in t.grouping.groups]
    tally: list[GroupVote] = []
    recorded = v.sv_reason is not None
    if recorded:
        for gi, vote in zip(v.sv_top_group[k].tolist(), v.sv_top_vote[k].tolist()):
            if gi >= 0:
                tally.append(GroupVote(int(gi), float(vote), sizes[gi], int(group_inst[gi]),
                                       sizes[gi] >= cfg.min_group_size))
        reason = VOTE_REASONS[int(v.sv_reason[k])]
    else:
        reason = "labelled" if v.sv_label[k] >= 0 else "not_recorded"
    wg = int(v.sv_group[k])
    wpts = float(v.group_points[wg]) if recorded and wg >= 0 and v.group_points is not None else float("nan")
    cleared: tuple[tuple[int, int], ...] = ()
    if v.span_cleared is not None and len(v.span_cleared):
        member = np.full(len(t.nodes), -1, np.int64)
        for gi, m in enumerate(t.grouping.groups):
            member[list(m)] = gi
        nodes = v.span_cleared[v.span_cleared[:, 1] == k, 0]
        cleared = tuple((int(n), int(member[n])) for n in nodes)
    return SupervoxelExplanation(
        span_cleared=cleared,
        k=k, label=int(v.sv_label[k]), winner_group=wg, winner_vote=float(v.sv_vote[k]),
        runner_up_vote=float(v.sv_runner_up[k]), coverage=float(v.sv_coverage[k]),
        min_coverage=float(cfg.min_coverage), tally=tuple(tally), reason=reason, recorded=recorded,
        winner_points=wpts, min_instance_points=int(cfg.min_instance_points),
    )


# keep the residual reasons importable from here for the viewer's words
RESIDUAL_TEXT = dict(zip(RESIDUAL_REASONS, (
    "replaced by its tree parent", "a tree root: no parent to substitute",
    "its parent lies on the support surface", "another leaf under its parent is grouped",
    "its parent was substituted already")))
