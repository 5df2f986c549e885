"""The four fragile spots of issue 13, each with the case that shows it and its fix.

(a) a super-voxel won by a group that is then dropped goes to the runner-up (``revote_dropped``);
(b) a non-background mask whose descendants are all background is substituted, not stranded
    (``substitute_stranded_parents``);
(c) without one mask per view, the mean linkage leaves same-view pairs out instead of counting 0;
(d) the trace stores the embeddings that were used (float32), so S_semantic recomputed from a
    saved trace equals the recorded one.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.segmentation.grouping import (
    GroupingConfig,
    NodeTable,
    SimilarityGraph,
    _Groups,
    run_grouping,
    semantic_similarity,
    spatial_similarity,
    stranded_parents,
)
from clutt3r_core.segmentation.trace import load_trace, save_trace
from clutt3r_core.segmentation.vote import VoteConfig, supervoxel_vote

from .._tiny_run import tiny_segmentation
from .test_grouping import K, X, as_keys, build, occ

# ---------------------------------------------------------------- (a) re-vote dropped groups


def _vote_case(cfg: VoteConfig):
    # group 0: one object over super-voxels 0-3 (100 points each); group 1: a speck that wins
    # super-voxel 3 (votes 2 > 1) but holds only 10 points, under min_instance_points = 30
    occupancy = np.zeros((3, 4), np.float32)
    occupancy[0, :4] = 1.0
    occupancy[1, 3] = 1.0
    occupancy[2, 3] = 1.0
    counts = np.array([100, 100, 100, 10])
    groups = ((0,), (1, 2))
    s = np.full((3, 3), np.nan, np.float32)
    return supervoxel_vote(groups, occupancy, counts, np.zeros(4, bool), s, 3, cfg)


def test_a_super_voxel_of_a_dropped_group_goes_to_the_runner_up():
    before = _vote_case(VoteConfig(revote_dropped=False))
    after = _vote_case(VoteConfig())
    assert before.sv_label.tolist() == [0, 0, 0, -1]  # the old behaviour: unlabelled
    assert after.sv_label.tolist() == [0, 0, 0, 0]
    # the record keeps the first vote's winner (the speck) for the explanation
    assert after.sv_group[3] == 1 and after.group_points[1] == 10
    assert after.instance_group.tolist() == [0]


def test_no_runner_up_that_fails_the_coverage_guard():
    # the runner-up covers only 0.3 of super-voxel 3: it stays unlabelled
    occupancy = np.zeros((3, 4), np.float32)
    occupancy[0, :3] = 1.0
    occupancy[0, 3] = 0.3
    occupancy[1, 3] = 1.0
    occupancy[2, 3] = 1.0
    res = supervoxel_vote(((0,), (1, 2)), occupancy, np.array([100, 100, 100, 10]), np.zeros(4, bool),
                          np.full((3, 3), np.nan, np.float32), 3, VoteConfig())
    assert res.sv_label.tolist() == [0, 0, 0, -1]


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 6), st.integers(3, 12), st.integers(0, 60))
def test_revote_only_adds_labels_and_every_instance_is_big_enough(seed, g, k, min_points):
    rng = np.random.default_rng(seed)
    n = g + 3
    occupancy = (rng.random((n, k)) * (rng.random((n, k)) < 0.4)).astype(np.float32)
    members = rng.integers(0, g, n)
    groups = tuple(tuple(int(i) for i in np.flatnonzero(members == j)) for j in range(g))
    groups = tuple(x for x in groups if x)
    counts = rng.integers(1, 40, k)
    support = rng.random(k) < 0.2
    s = np.full((n, n), np.nan, np.float32)
    cfg = VoteConfig(min_instance_points=min_points, min_coverage=0.3)
    off = supervoxel_vote(groups, occupancy, counts, support, s, 3, replace(cfg, revote_dropped=False))
    on = supervoxel_vote(groups, occupancy, counts, support, s, 3, cfg)
    g_off = np.append(off.instance_group, -1)[off.sv_label]  # group of each super-voxel, -1 = none
    g_on = np.append(on.instance_group, -1)[on.sv_label]
    kept = off.sv_label >= 0
    assert np.array_equal(g_on[kept], g_off[kept])  # what was labelled stays with the same group
    for inst in range(len(on.scores)):  # every instance holds at least min_instance_points
        assert counts[on.sv_label == inst].sum() >= min_points
    assert not (on.sv_label[support] >= 0).any()


# ---------------------------------------------------------------- (b) stranded parents


def _stranded_case():
    # view 0: object mask 1 (not background) whose only child, mask 2, lies on the table
    # (background); views 1 and 2 see the object whole
    spec = [(0, 1, None, occ(*X)), (0, 2, 1, occ(10, 11)), (1, 1, None, occ(*X)), (2, 1, None, occ(*X))]
    nodes, sim, O, idx, V = build(spec)
    bg = np.zeros(len(nodes), bool)
    bg[idx[(0, 2)]] = True
    nodes = replace(nodes, background=bg)
    s_spat, s_sem = sim.s_spatial.copy(), sim.s_semantic.copy()
    s_spat[bg, :] = s_spat[:, bg] = np.nan
    s_sem[bg, :] = s_sem[:, bg] = np.nan
    return nodes, SimilarityGraph(s_spat, s_sem), idx, V


def test_a_parent_of_only_background_leaves_is_substituted_not_stranded():
    nodes, sim, idx, V = _stranded_case()
    assert stranded_parents(nodes).tolist() == [idx[(0, 1)]]
    before = run_grouping(nodes, sim, V, GroupingConfig(substitute_stranded_parents=False))
    after = run_grouping(nodes, sim, V, GroupingConfig())
    assert as_keys(before, nodes) == [((1, 1), (2, 1))]  # the object is missing in view 0
    assert as_keys(after, nodes) == [((0, 1), (1, 1), (2, 1))]
    assert [(s.parent, s.replaced) for s in after.substitutions] == [(idx[(0, 1)], ())]


def test_stranded_parents_need_substitution():
    nodes, sim, idx, V = _stranded_case()
    res = run_grouping(nodes, sim, V, GroupingConfig(substitution=False))
    assert as_keys(res, nodes) == [((1, 1), (2, 1))]


def test_a_stranded_parent_below_a_grouped_node_is_left_alone():
    # view 0: mask 3 contains mask 1 (stranded: its only child 2 is background) and leaf 4, which
    # stays residual; 3 is substituted for 4 first, so 1 (on the same path as 3) must not join too
    spec = [(0, 3, None, occ(*X, 10, 11)), (0, 1, 3, occ(*X)), (0, 2, 1, occ(10, 11)), (0, 4, 3, occ(9)),
            (1, 1, None, occ(4, 5))]
    nodes, sim, O, idx, V = build(spec)
    bg = np.zeros(len(nodes), bool)
    bg[idx[(0, 2)]] = True
    nodes = replace(nodes, background=bg)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    in_groups = {nodes.key(i) for g in res.groups for i in g}
    # at most one node of each root-to-leaf path of view 0 is in a group
    assert not ({(0, 3), (0, 1)} <= in_groups)


# ---------------------------------------------------------------- (c) mean linkage without an edge


def test_same_view_pairs_do_not_dilute_the_mean_linkage():
    # without one mask per view: group {0:1, 1:1} and mask 0:2 (same view as 0:1). Only (1:1, 0:2)
    # has an edge, S = 0.6: the mean is 0.6 (>= tau_spat 0.5), not 0.3 as when the missing pair counted 0
    o_a = occ(0, 1, 2, 3, 4)
    spec = [(0, 1, None, o_a), (1, 1, None, o_a), (0, 2, None, occ(0, 1, 2))]
    nodes, sim, O, idx, V = build(spec)
    assert sim.s_spatial[idx[(1, 1)], idx[(0, 2)]] == np.float32(0.6)
    cfg = GroupingConfig(one_mask_per_view=False, use_semantic=False)
    res = run_grouping(nodes, sim, V, cfg)
    assert as_keys(res, nodes) == [((0, 1), (0, 2), (1, 1))]
    m = res.merges[-1]
    assert m.spatial == np.float32(0.6) or abs(m.spatial - 0.6) < 1e-6


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(2, 9))
def test_with_one_mask_per_view_the_mean_over_edges_is_the_mean_over_all_pairs(seed, n_groups):
    # so ours (one mask per view on) gives the same groups as before the fix
    rng = np.random.default_rng(seed)
    n, views = 12, 4
    view = rng.integers(0, views, n).astype(np.int32)
    O = (rng.random((n, K)) < 0.3).astype(np.float32)
    s = spatial_similarity(O, np.full(K, 1.0 / K))
    s[view[:, None] == view[None, :]] = np.nan
    groups: list[list[int]] = [[] for _ in range(n_groups)]
    for i in range(n):  # groups that never hold two masks of a view
        for g in rng.permutation(n_groups):
            if all(view[j] != view[i] for j in groups[g]):
                groups[int(g)].append(i)
                break
        else:
            groups.append([i])
    state = _Groups([g for g in groups if g], s, s, view, views)
    ok = state.valid(True)
    new, old = state.mean(0), state.mean(0, defined_only=False)
    assert np.array_equal(new[ok], old[ok])


# ---------------------------------------------------------------- (d) embeddings in the trace


def test_the_trace_stores_the_embeddings_that_were_used(tmp_path):
    tr = tiny_segmentation().trace
    back = load_trace(save_trace(tr, tmp_path / "trace"))
    assert back.embeddings.dtype == np.float32
    assert np.array_equal(back.embeddings, tr.embeddings)
    # S_semantic recomputed from the stored embeddings is the recorded one, bit for bit
    again = semantic_similarity(back.embeddings)
    edge = np.isfinite(back.s_semantic)
    assert np.array_equal(again[edge], back.s_semantic[edge])
    assert np.array_equal(back.vote.sv_top_vote, tr.vote.sv_top_vote)
