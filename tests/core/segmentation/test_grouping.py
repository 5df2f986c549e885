"""Hand-built grouping cases: nodes with known occupancy over a few super-voxels."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.segmentation.grouping import (
    GroupingConfig,
    NodeTable,
    SimilarityGraph,
    reunion_weights,
    run_grouping,
    same_view_containment,
    semantic_similarity,
    spatial_similarity,
)
from clutt3r_core.segmentation.vote import VoteConfig, supervoxel_vote

K = 12  # super-voxels: object X = 0..3, object Y = 4..9, object Z = 10..11 (unused by some cases)
X = list(range(0, 4))
Y = list(range(4, 10))


def occ(*svs):
    o = np.zeros(K, np.float32)
    o[list(svs)] = 1.0
    return o


def build(spec, emb=None):
    """spec: list of (frame, mask_id, parent_mask_id or None, occupancy row)."""
    spec = sorted(spec, key=lambda s: (s[0], s[1]))
    frames = sorted({s[0] for s in spec})
    index = {(s[0], s[1]): i for i, s in enumerate(spec)}
    parent = np.array([index[(s[0], s[2])] if s[2] is not None else -1 for s in spec], np.int32)
    has_child = np.zeros(len(spec), bool)
    has_child[parent[parent >= 0]] = True
    nodes = NodeTable(
        frame=np.array([s[0] for s in spec], np.int32),
        view=np.array([frames.index(s[0]) for s in spec], np.int32),
        mask_id=np.array([s[1] for s in spec], np.int32),
        parent=parent,
        is_leaf=~has_child,
        background=np.zeros(len(spec), bool),
    )
    O = np.stack([s[3] for s in spec])
    s_spat = spatial_similarity(O, np.full(K, 1.0 / K))
    if emb is None:
        emb = np.eye(len(spec), 8, dtype=np.float32) if len(spec) <= 8 else np.eye(len(spec), dtype=np.float32)
    s_sem = semantic_similarity(emb)
    same = nodes.view[:, None] == nodes.view[None, :]
    s_spat[same] = np.nan
    s_sem[same] = np.nan
    return nodes, SimilarityGraph(s_spat, s_sem), O, index, len(frames)


def as_keys(result, nodes):
    return sorted(tuple(sorted(nodes.key(i) for i in g)) for g in result.groups)


def test_spatial_similarity_is_weighted_jaccard():
    O = np.array([[1.0, 0.5, 0.0], [0.5, 0.5, 1.0]], np.float32)
    w = np.array([0.2, 0.3, 0.5], np.float32)
    s = spatial_similarity(O, w)
    expect = (0.2 * 0.5 + 0.3 * 0.5) / (0.2 * 1.0 + 0.3 * 0.5 + 0.5 * 1.0)
    assert s[0, 1] == pytest.approx(expect, rel=1e-5)
    assert s[0, 0] == pytest.approx(1.0)


def test_parent_with_two_children_across_three_views():
    spec = [
        (0, 1, None, occ(*X, *Y)),  # under-segmented union: parent
        (0, 2, 1, occ(*X)),
        (0, 3, 1, occ(*Y)),
        (1, 1, None, occ(*X)),
        (1, 2, None, occ(*Y)),
        (2, 5, None, occ(*X[:3])),
        (2, 6, None, occ(*Y)),
    ]
    nodes, sim, O, idx, V = build(spec)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    assert as_keys(res, nodes) == [((0, 2), (1, 1), (2, 5)), ((0, 3), (1, 2), (2, 6))]
    assert all(m.stage == "spatial" for m in res.merges) and len(res.merges) == 4
    assert res.substitutions == ()
    # merge scores never increase within stage 1 here, and each is >= tau_spat
    assert all(m.score >= 0.5 for m in res.merges)


def test_under_segmentation_in_one_view_only_stays_out_and_loses_the_vote():
    Yb = list(range(4, 12))  # Y bigger than X, so the union's Jaccard with X is 4/12 and with Y 8/12
    spec = [
        (0, 1, None, occ(*X, *Yb)),  # the only mask of view 0: under-segmented
        (1, 1, None, occ(*X)),
        (1, 2, None, occ(*Yb)),
        (2, 1, None, occ(*X)),
        (2, 2, None, occ(*Yb)),
    ]
    nodes, sim, O, idx, V = build(spec)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    groups = as_keys(res, nodes)
    # Y's group absorbs the union (mean linkage 8/12 >= 0.5) or not; X's group never does, and
    # two masks of view 1 or 2 never share a group
    x_group = [g for g in groups if (1, 1) in g][0]
    assert (0, 1) not in x_group and (1, 2) not in x_group and (2, 2) not in x_group
    vote = supervoxel_vote(res.groups, O, np.full(K, 10), np.zeros(K, bool), sim.s_spatial, V, VoteConfig())
    inst_of_sv = vote.sv_label
    # X's super-voxels all go to one instance and Y's to another
    assert len(set(inst_of_sv[X].tolist())) == 1 and len(set(inst_of_sv[Yb].tolist())) == 1
    assert inst_of_sv[X[0]] != inst_of_sv[Yb[0]] and inst_of_sv[X[0]] >= 0


def test_over_segmented_object_is_grouped_only_after_substitution():
    # object Y seen whole in view 0 only as parent of two halves split left/right, in view 1
    # split top/bottom: halves of different views overlap by 2/6 (< tau_spat), so stage 1 fails
    spec = [
        (0, 1, None, occ(*range(4, 12))),
        (0, 2, 1, occ(4, 5, 6, 7)),
        (0, 3, 1, occ(8, 9, 10, 11)),
        (1, 1, None, occ(*range(4, 12))),
        (1, 2, 1, occ(4, 5, 8, 9)),
        (1, 3, 1, occ(6, 7, 10, 11)),
    ]
    nodes, sim, O, idx, V = build(spec)
    without = run_grouping(nodes, sim, V, GroupingConfig(substitution=False))
    assert all(len(g) == 1 for g in without.groups)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    assert as_keys(res, nodes) == [((0, 1), (1, 1))]
    assert len(res.substitutions) == 2
    assert {nodes.key(s.parent) for s in res.substitutions} == {(0, 1), (1, 1)}
    kinds = [k for k, _ in res.events]
    assert kinds == ["substitution", "substitution", "merge"]


def test_substitution_needs_all_siblings_residual():
    # the parent's other child is grouped, so the residual child is not substituted
    spec = [
        (0, 1, None, occ(*X, *Y)),
        (0, 2, 1, occ(*X)),
        (0, 3, 1, occ(10)),  # speck: residual
        (1, 1, None, occ(*X)),
    ]
    nodes, sim, O, idx, V = build(spec)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    assert res.substitutions == ()
    assert ((0, 2), (1, 1)) in as_keys(res, nodes)


def test_identical_masks_never_share_a_group():
    spec = [
        (0, 1, None, occ(*X)),
        (0, 2, None, occ(*X)),  # duplicate in the same view
        (1, 1, None, occ(*X)),
        (2, 1, None, occ(*X)),
    ]
    nodes, sim, O, idx, V = build(spec)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    for g in res.groups:
        views = nodes.view[list(g)]
        assert len(set(views.tolist())) == len(views)
    sizes = sorted(len(g) for g in res.groups)
    assert sizes == [1, 3]
    # ties go to the first pair in canonical order: (0, 1) is the one grouped
    assert ((0, 1), (1, 1), (2, 1)) in as_keys(res, nodes)


def test_semantic_stage_merges_whole_groups():
    # two halves of an object seen from opposite sides share only a rim super-voxel (3) but look alike
    spec = [
        (0, 1, None, occ(0, 1, 3)),
        (1, 1, None, occ(0, 1, 3)),
        (2, 1, None, occ(2, 3, 4)),
        (3, 1, None, occ(2, 3, 4)),
    ]
    emb = np.tile(np.array([[1.0, 0.0]], np.float32), (4, 1))
    nodes, sim, O, idx, V = build(spec, emb=emb)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    assert as_keys(res, nodes) == [((0, 1), (1, 1), (2, 1), (3, 1))]
    assert [m.stage for m in res.merges] == ["spatial", "spatial", "semantic"]
    assert 0 < res.merges[-1].spatial < 0.5
    no_sem = run_grouping(nodes, sim, V, GroupingConfig(use_semantic=False))
    assert len(no_sem.groups) == 2


def test_semantic_stage_never_joins_look_alikes_that_share_no_super_voxel():
    # two same-coloured objects far apart: S_semantic 1, S_spatial exactly 0
    spec = [
        (0, 1, None, occ(0, 1)),
        (1, 1, None, occ(0, 1)),
        (2, 1, None, occ(6, 7)),
        (3, 1, None, occ(6, 7)),
    ]
    emb = np.tile(np.array([[1.0, 0.0]], np.float32), (4, 1))
    nodes, sim, O, idx, V = build(spec, emb=emb)
    res = run_grouping(nodes, sim, V, GroupingConfig())
    assert len(res.groups) == 2 and all(m.stage == "spatial" for m in res.merges)
    literal = run_grouping(nodes, sim, V, GroupingConfig(semantic_needs_overlap=False))
    assert len(literal.groups) == 1 and literal.merges[-1].stage == "semantic"


def _split_in_two_views() -> list:
    """One object split into the same two halves in views 0 and 1 and seen whole in views 2 and 3
    (the reunion tests' scene)."""
    left, right = (4, 5, 6, 7), (8, 9, 10, 11)
    return [
        (0, 1, None, occ(*left)),
        (0, 2, None, occ(*right)),
        (1, 1, None, occ(*left)),
        (1, 2, None, occ(*right)),
        (2, 1, None, occ(*range(4, 12))),
        (3, 1, None, occ(*range(4, 12))),
    ]


def test_reunion_joins_an_object_split_into_parts_in_two_views_only_when_enabled():
    # object Y split into the same two halves in views 0 and 1, seen whole in views 2 and 3: the
    # wholes join the left halves (S 0.5), and the one-mask-per-view rule keeps the right halves out
    nodes, sim, O, idx, V = build(_split_in_two_views())
    plain = run_grouping(nodes, sim, V, GroupingConfig())
    assert sorted(len(g) for g in plain.groups) == [2, 4]
    res = run_grouping(nodes, sim, V, GroupingConfig(reunion_tau=0.25))
    assert len(res.groups) == 1 and res.merges[-1].stage == "reunion"
    assert res.merges[-1].score >= 0.25
    # two different objects that share views and never overlap in 3D are never reunited
    spec2 = [(f, m, None, occ(*(X if m == 1 else Y))) for f in range(3) for m in (1, 2)]
    nodes2, sim2, _, _, V2 = build(spec2)
    assert len(run_grouping(nodes2, sim2, V2, GroupingConfig(reunion_tau=0.25)).groups) == 2



def test_reunion_containment_gate_keeps_a_mask_that_holds_the_other_apart():
    # the reunion case above; per view, pixel overlaps of its two masks (node order, diagonal =
    # areas). Side by side (the parts of one object) the gate lets the reunion through; where a
    # mask of view 0 holds the other one (a mask spanning the object and a neighbour) it does not
    nodes, sim, O, idx, V = build(_split_in_two_views())
    apart = [np.array([[100, 0], [0, 80]]), np.array([[90, 3], [3, 70]]), np.array([[200]]), np.array([[210]])]
    held = [np.array([[100, 100], [100, 300]]), apart[1], apart[2], apart[3]]
    gate = GroupingConfig(reunion_tau=0.25, reunion_max_contain=0.5)
    assert len(run_grouping(nodes, sim, V, gate, overlaps=apart).groups) == 1
    kept = run_grouping(nodes, sim, V, gate, overlaps=held)
    assert sorted(len(g) for g in kept.groups) == [2, 4] and all(m.stage != "reunion" for m in kept.merges)
    # the gate off (1) or no overlaps: the reunion as before
    assert len(run_grouping(nodes, sim, V, GroupingConfig(reunion_tau=0.25), overlaps=held).groups) == 1
    assert len(run_grouping(nodes, sim, V, gate).groups) == 1
    # the reunited group counts each view once in its confidence: the two right halves (views 0
    # and 1, which the left halves' group already held) weigh 0, every other mask 1
    res = run_grouping(nodes, sim, V, gate, overlaps=apart)
    w = reunion_weights(res.merges, nodes.view)
    assert w.sum() == len(set(nodes.view.tolist())) == 4
    assert (reunion_weights(run_grouping(nodes, sim, V, GroupingConfig()).merges, nodes.view) == 1).all()
    # the semantic gate: a pair whose mean S_semantic is under it is not reunited
    sem = res.merges[-1].semantic
    assert len(run_grouping(nodes, sim, V, replace(gate, reunion_min_semantic=sem - 1e-3), overlaps=apart).groups) == 1
    assert len(run_grouping(nodes, sim, V, replace(gate, reunion_min_semantic=sem + 1e-3), overlaps=apart).groups) == 2


@settings(max_examples=30, deadline=None)
@given(st.lists(st.integers(1, 4), min_size=1, max_size=4), st.integers(0, 2**31 - 1))
def test_same_view_containment_is_symmetric_bounded_and_within_views(sizes, seed):
    rng = np.random.default_rng(seed)
    view = np.concatenate([np.full(n, v) for v, n in enumerate(sizes)])
    overlaps = []
    for n in sizes:  # overlaps of random pixel masks: a true intersection matrix
        bits = rng.random((n, 50)) < 0.4
        overlaps.append(bits.astype(np.int64) @ bits.T.astype(np.int64))
    c = same_view_containment(view, overlaps)
    assert np.allclose(c, c.T) and (c >= 0).all() and (c <= 1 + 1e-6).all()
    assert (c[view[:, None] != view[None, :]] == 0).all() and (np.diag(c) == 0).all()


def test_empty_input():
    nodes = NodeTable(*(np.zeros(0, np.int32) for _ in range(4)), np.zeros(0, bool), np.zeros(0, bool))
    sim = SimilarityGraph(np.zeros((0, 0), np.float32), np.zeros((0, 0), np.float32))
    res = run_grouping(nodes, sim, 0, GroupingConfig())
    assert res.groups == () and res.merges == ()


def test_semantic_min_spatial_keeps_look_alikes_apart_that_share_a_sliver():
    # two same-coloured objects whose masks share only a sliver of one super-voxel (a stray mask
    # edge): mean S_spatial 0.005, above 0, so the overlap gate alone lets stage 2 join them
    x = occ(*X)
    x[4] = 0.05
    spec = [(0, 1, None, x), (1, 1, None, x), (2, 1, None, occ(*Y)), (3, 1, None, occ(*Y))]
    emb = np.tile(np.array([[1.0, 0.0]], np.float32), (4, 1))
    nodes, sim, O, idx, V = build(spec, emb=emb)
    plain = run_grouping(nodes, sim, V, GroupingConfig(semantic_min_spatial=0.0))
    assert len(plain.groups) == 1 and 0 < plain.merges[-1].spatial < 0.01
    gated = run_grouping(nodes, sim, V, GroupingConfig())  # the default gate (0.01, session 9)
    assert GroupingConfig().semantic_min_spatial == 0.01
    assert len(gated.groups) == 2 and all(m.stage == "spatial" for m in gated.merges)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.sampled_from([0.0, 0.01, 0.05, 0.2]))
def test_every_semantic_merge_meets_semantic_min_spatial(seed, t):
    # random sparse occupancies and embeddings over 4 views: no stage-2 merge below the gate
    rng = np.random.default_rng(seed)
    spec = []
    for f in range(4):
        for m in range(1, 4):
            row = (rng.random(K) < 0.3) * rng.random(K)
            spec.append((f, m, None, row.astype(np.float32)))
    emb = rng.normal(size=(len(spec), 3)).astype(np.float32)
    emb[:, 0] += 3.0  # look-alikes: most semantic similarities above tau_sem
    nodes, sim, O, idx, V = build(spec, emb=emb)
    res = run_grouping(nodes, sim, V, GroupingConfig(semantic_min_spatial=t))
    assert all(m.spatial > 0 and m.spatial >= t - 1e-6 for m in res.merges if m.stage == "semantic")
