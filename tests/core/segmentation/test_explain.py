"""Recorded explanations of grouping decisions not taken, and explain_pair / explain_supervoxel.

Hand-built graphs where the blocking rule is known, a hypothesis property over random leaf
graphs (recording never changes the result; every pair apart gets a rule its numbers back),
the trace round trip, old traces without the records, and the ``clutt3r explain`` command.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutt3r_core.config import SegmentConfig
from clutt3r_core.errors import SceneError
from clutt3r_core.explain import RULE_TEXT, explain_pair, explain_supervoxel
from clutt3r_core.segmentation.grouping import (
    GroupingConfig,
    NodeTable,
    SimilarityGraph,
    group_nodes,
    run_grouping,
    semantic_similarity,
    spatial_similarity,
)
from clutt3r_core.segmentation.trace import Trace, load_trace, save_trace
from clutt3r_core.segmentation.vote import VOTE_REASONS, VoteConfig, supervoxel_vote

K = 12


def occ(*svs, value=1.0):
    o = np.zeros(K, np.float32)
    o[list(svs)] = value
    return o


def make_trace(spec, emb=None, vote_cfg=VoteConfig(), support=None, counts=None, gcfg=GroupingConfig()):
    """spec: (frame, mask id, parent mask id or None, occupancy row) -> a Trace of the whole run."""
    spec = sorted(spec, key=lambda s: (s[0], s[1]))
    frames = sorted({s[0] for s in spec})
    index = {(s[0], s[1]): i for i, s in enumerate(spec)}
    parent = np.array([index[(s[0], s[2])] if s[2] is not None else -1 for s in spec], np.int32)
    has_child = np.zeros(len(spec), bool)
    has_child[parent[parent >= 0]] = True
    nodes = NodeTable(np.array([s[0] for s in spec], np.int32), np.array([frames.index(s[0]) for s in spec], np.int32),
                      np.array([s[1] for s in spec], np.int32), parent, ~has_child, np.zeros(len(spec), bool))
    O = np.stack([s[3] for s in spec]).astype(np.float32)
    s_spat = spatial_similarity(O, np.full(K, 1.0 / K))
    emb = np.eye(len(spec), max(len(spec), 8), dtype=np.float32) if emb is None else emb
    s_sem = semantic_similarity(emb)
    same = nodes.view[:, None] == nodes.view[None, :]
    s_spat[same] = np.nan
    s_sem[same] = np.nan
    res = run_grouping(nodes, SimilarityGraph(s_spat, s_sem), len(frames), gcfg)
    vote = supervoxel_vote(res.groups, O, np.full(K, 10) if counts is None else counts,
                           np.zeros(K, bool) if support is None else support, s_spat, len(frames), vote_cfg)
    cfg = SegmentConfig(grouping=gcfg, vote=vote_cfg)
    return Trace(frames=np.array(frames, np.int32), trees=(), nodes=nodes, embeddings=emb, occupancy=O,
                 s_spatial=s_spat, s_semantic=s_sem, grouping=res, vote=vote, timings=(), embedder="test",
                 config=cfg), index


X = [0, 1, 2, 3]
Z = [10, 11]


def test_one_mask_per_view_blocks_a_part_and_is_recorded():
    # X split into two parts in view 0, whole in views 1 and 2: the second part would reach
    # tau_spat with the X group but that group already holds a mask of view 0
    spec = [(0, 1, None, occ(0, 1, 2)), (0, 2, None, occ(1, 2, 3)), (1, 1, None, occ(*X)), (2, 1, None, occ(*X))]
    t, ix = make_trace(spec)
    b = t.grouping.blocked
    assert len(b.a) == 1 and b.rule[0] == 1 and b.score[0] >= 0.5
    e = explain_pair(t, (0, 2), (1, 1))
    assert not e.together and e.rule == "one_mask_per_view" and e.checks[0].recorded
    assert e.checks[0].shared_views == (0,)
    # fates diverged when part 0:1 joined the X group (the step after which they shared view 0)
    joined = next(s for s in range(len(t.grouping.events) + 1) if ix[(0, 1)] in
                  next(g for g in t.groups_at(s) if ix[(1, 1)] in g))
    assert e.diverge_step == joined
    # mean linkage over the pairs with an edge: (1:1, 0:2) and (2:1, 0:2), 0.75 each; the
    # same-view pair (0:1, 0:2) has none and is left out (it counted as 0 before issue 13)
    assert "one mask per view" in e.text() and "0.750 vs tau 0.50" in e.text()
    assert explain_pair(t, (0, 1), (0, 2)).rule == "same_view"
    m = explain_pair(t, (1, 1), (2, 1))
    assert m.together and m.rule == "merged" and m.merge_event == 0 and m.diverge_step == 1


def test_overlap_gate_and_threshold():
    # two look-alike objects (same embedding) that never share a super-voxel: the gate; a third
    # different-looking one: the semantic threshold
    e1 = np.zeros((4, 8), np.float32)
    e1[:, 0] = 1.0
    e1[3] = np.eye(8)[5]
    spec = [(0, 1, None, occ(*X)), (1, 1, None, occ(*Z)), (2, 1, None, occ(4, 5)), (3, 1, None, occ(6, 7))]
    t, _ = make_trace(spec, emb=e1)
    e = explain_pair(t, (0, 1), (1, 1))
    assert e.rule == "below_tau_spat" and e.final_rule == "overlap_gate"
    gate = [c for c in e.checks if c.stage == "semantic"][0]
    assert gate.recorded and gate.semantic == pytest.approx(1.0) and gate.spatial == 0.0
    f = explain_pair(t, (0, 1), (3, 1))
    assert f.final_rule == "below_tau_sem"
    sem = [c for c in f.checks if c.stage == "semantic"][0]
    assert sem.score < sem.tau and not sem.recorded and "overlap_gate" in sem.also
    stops = t.grouping.stops
    assert [s.stage for s in stops] == ["spatial", "semantic"]
    assert stops[1].blocked_rule == "overlap_gate" and stops[1].blocked_score == pytest.approx(1.0)
    assert all(not s.best_score >= s.tau for s in stops)  # every stage stopped below its tau (or no pair)


def test_residual_not_substituted_is_explained():
    # view 0: parent P over leaves a, b; a is grouped with view 1's mask, b stays alone
    spec = [(0, 1, None, occ(*X, 4, 5)), (0, 2, 1, occ(*X)), (0, 3, 1, occ(4, 5)), (1, 1, None, occ(*X))]
    t, ix = make_trace(spec)
    r = t.grouping.residuals
    i = list(r.node).index(ix[(0, 3)])
    assert r.reason[i] == 3 and r.other[i] == ix[(0, 2)]  # sibling_grouped, naming the grouped leaf
    e = explain_pair(t, (0, 3), (1, 1))
    assert "another leaf under its parent is grouped" in e.text()


def test_supervoxel_reasons():
    spec = [(0, 1, None, occ(0, 1, 2)), (1, 1, None, occ(0, 1, 2)), (0, 2, None, occ(5, value=0.3)),
            (1, 2, None, occ(8, 9)), (2, 1, None, occ(8, 9))]
    counts = np.full(K, 10)
    counts[8:10] = 1  # the group on 8, 9 wins 2 points only: not an instance
    support = np.zeros(K, bool)
    support[2] = True
    t, _ = make_trace(spec, counts=counts, support=support, vote_cfg=VoteConfig(min_instance_points=5))
    reason = lambda k: explain_supervoxel(t, k).reason  # noqa: E731
    assert reason(0) == "labelled" and reason(2) == "support" and reason(5) == "coverage"
    assert reason(8) == "group_dropped" and reason(11) == "no_vote"
    s = explain_supervoxel(t, 0)
    assert s.tally[0].vote == pytest.approx(2.0) and s.tally[0].n_masks == 2 and s.winner_vote == pytest.approx(2.0)
    assert "min_instance_points 5" in explain_supervoxel(t, 8).text()
    assert "0.30" in explain_supervoxel(t, 5).text()  # the coverage that failed the guard
    with pytest.raises(SceneError, match="out of range"):
        explain_supervoxel(t, K)


@st.composite
def leaf_graphs(draw):
    v = draw(st.integers(2, 4))
    spec = []
    for f in range(v):
        for m in range(draw(st.integers(1, 4))):
            svs = draw(st.lists(st.integers(0, K - 1), min_size=1, max_size=5, unique=True))
            spec.append((f, m + 1, None, occ(*svs)))
    emb = np.asarray(draw(st.lists(st.lists(st.floats(-1, 1), min_size=4, max_size=4), min_size=len(spec),
                                   max_size=len(spec))), np.float32) + np.eye(len(spec), 4, dtype=np.float32)
    emb /= np.maximum(np.linalg.norm(emb, axis=1, keepdims=True), 1e-6)
    return spec, emb


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(leaf_graphs(), st.sampled_from([0.3, 0.5]), st.booleans(), st.sampled_from([0.0, 0.01, 0.2]))
def test_every_pair_apart_has_a_rule_its_numbers_back(graph, tau, gate, min_spatial):
    spec, emb = graph
    gcfg = GroupingConfig(tau_spat=tau, tau_sem=0.6, semantic_needs_overlap=gate, semantic_min_spatial=min_spatial)
    t, _ = make_trace(spec, emb=emb, gcfg=gcfg)
    n = t.nodes
    # recording never changes the result
    start = [[i] for i in range(len(n))]
    sim = SimilarityGraph(t.s_spatial, t.s_semantic)
    assert group_nodes(start, sim, n.view, int(n.view.max()) + 1, gcfg)[0] == \
        group_nodes(start, sim, n.view, int(n.view.max()) + 1, gcfg, record=[])[0]
    b = t.grouping.blocked
    assert np.all(b.score >= np.array([t.grouping.stops[s].tau for s in b.stop]) - 1e-9)
    final = {i: g for g in t.grouping.groups for i in g}
    for i in range(len(n)):
        for j in range(i + 1, len(n)):
            e = explain_pair(t, i, j)
            assert e.together == (final[i] == final[j])
            if e.together:
                m = t.grouping.merges[t.grouping.events[e.merge_event][1]]
                assert set(m.a + m.b) >= {i, j}
                # together, and named "group_dropped" exactly when the vote did not keep the group
                assert (e.rule == "group_dropped") == (e.instance_a < 0)
                continue
            assert e.rule in RULE_TEXT and e.rule not in ("merged", "not_recorded")
            for c in e.checks:
                if c.rule.startswith("below_tau"):
                    assert c.score < c.tau
                elif c.rule == "one_mask_per_view":
                    assert c.shared_views
                elif c.rule == "overlap_gate":  # no shared super-voxel, or under semantic_min_spatial
                    assert not (c.spatial > 0.0 and c.spatial >= min_spatial)


def test_trace_round_trip_and_old_traces(tmp_path):
    spec = [(0, 1, None, occ(0, 1, 2)), (0, 2, None, occ(1, 2, 3)), (1, 1, None, occ(*X)), (2, 1, None, occ(*X))]
    t, _ = make_trace(spec)
    back = load_trace(save_trace(t, tmp_path / "new"))
    assert repr(back.grouping.stops) == repr(t.grouping.stops)  # NaN (no pair left) reads back NaN
    for f in ("stop", "a", "b", "rule", "score"):
        assert np.array_equal(getattr(back.grouping.blocked, f), getattr(t.grouping.blocked, f))
    for f in ("node", "reason", "other"):
        assert np.array_equal(getattr(back.grouping.residuals, f), getattr(t.grouping.residuals, f))
    assert np.array_equal(back.vote.sv_reason, t.vote.sv_reason)
    assert np.array_equal(back.vote.sv_top_vote, t.vote.sv_top_vote)  # float32 on disk since issue 13
    assert explain_pair(back, (0, 2), (1, 1)).text() == explain_pair(t, (0, 2), (1, 1)).text()

    # a trace written before these records existed: strip them from the files
    old = tmp_path / "old"
    save_trace(t, old)
    meta = json.loads((old / "trace.json").read_text())
    del meta["stops"]
    (old / "trace.json").write_text(json.dumps(meta))
    z = dict(np.load(old / "trace.npz"))
    z = {k: a for k, a in z.items() if not k.startswith(("blocked_", "residual_", "sv_top", "sv_reason", "group_p"))}
    np.savez_compressed(old / "trace.npz", **z)
    o = load_trace(old)
    assert o.grouping.stops is None and o.vote.sv_reason is None
    e = explain_pair(o, (0, 2), (1, 1))
    assert not e.recorded and e.rule == "not_recorded" and "not recorded in this run" in e.text()
    assert explain_pair(o, (0, 1), (0, 2)).rule == "same_view"  # needs no record
    s = explain_supervoxel(o, 11)
    assert s.reason == "not_recorded" and "not recorded in this run" in s.text()


def test_explain_command(tmp_path, capsys):
    from clutt3r_core.commands.explain import explain_command

    spec = [(0, 1, None, occ(0, 1, 2)), (0, 2, None, occ(1, 2, 3)), (1, 1, None, occ(*X)), (2, 1, None, occ(*X))]
    t, _ = make_trace(spec)
    run = tmp_path / "run"
    save_trace(t, run / "trace")
    explain_command(run, masks=("0:2", "1:1"), supervoxel=0, json=True)
    lines = capsys.readouterr().out.strip().splitlines()
    pair, sv = (json.loads(x) for x in lines)
    assert pair["rule"] == "one_mask_per_view" and pair["key_a"] == [0, 2]
    assert sv["k"] == 0 and sv["reason"] in VOTE_REASONS
    explain_command(run, masks=("0:2", "1:1"))
    assert "first kept apart by: one_mask_per_view" in capsys.readouterr().out
    with pytest.raises(SceneError, match="no mask 7:1"):
        explain_command(run, masks=("7:1", "1:1"))
    with pytest.raises(SceneError, match="FRAME:MASK"):
        explain_command(run, masks=("x", "1:1"))


def test_a_tied_vote_is_called_a_tie():
    # two single-mask groups that never merge (Jaccard 1/7, orthogonal embeddings) both cover
    # super-voxel 0 fully: equal votes, the lower group index wins
    spec = [(0, 1, None, occ(0, 1, 2, 3)), (1, 1, None, occ(0, 4, 5, 6))]
    t, _ = make_trace(spec)
    s = explain_supervoxel(t, 0)
    assert s.winner_vote == s.runner_up_vote == pytest.approx(1.0) and s.winner_group == 0
    assert "a tie" in s.text()
    assert "a tie" not in explain_supervoxel(t, 1).text()
