"""Fragment absorption (segmentation/refine.py) on hand-made votes and in the pipeline."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.grouping import GroupingResult
from clutt3r_core.segmentation.refine import ABSORB_STAGE, RefineConfig, absorb_fragments, won_fractions
from clutt3r_core.segmentation.vote import VoteConfig, supervoxel_vote

# super-voxels 0-9 are object A (100 raw points each), 10-19 object B; 20 is a small sliver
COUNTS = np.array([100] * 20 + [20], np.float64)
SUPPORT = np.zeros(21, bool)


def occ_rows(*spans: tuple[int, int, float]) -> np.ndarray:
    row = np.zeros(21, np.float32)
    for a, b, v in spans:
        row[a:b] = v
    return row


def scenario(frag_on_a: float = 0.9, frag_sliver: float = 1.0):
    """Nodes 0-2: whole-A masks (3 views); 3-5: whole-B masks; 6-7: part masks of A (2 views) that
    also cover the sliver super-voxel 20, which only they touch."""
    occ = np.stack([occ_rows((0, 10, 1.0), (20, 21, 0.3))] * 3 + [occ_rows((10, 20, 1.0))] * 3
                   + [occ_rows((0, 5, frag_on_a), (20, 21, frag_sliver))] * 2)
    view = np.array([0, 1, 2, 0, 1, 2, 3, 4])
    groups = ((0, 1, 2), (3, 4, 5), (6, 7))
    s = np.full((8, 8), np.nan, np.float32)
    s[view[:, None] != view[None, :]] = 0.3
    grouping = GroupingResult(groups=groups, merges=(), substitutions=(), events=())
    cfg = VoteConfig(min_coverage=0.0, min_instance_points=0)

    def revote(g):
        return supervoxel_vote(g, occ, COUNTS, SUPPORT, s, 5, cfg)

    return grouping, revote(groups), occ, s, revote


def test_a_fragment_joins_the_instance_that_won_its_footprint():
    grouping, vote, occ, s, revote = scenario()
    assert len(vote.instance_group) == 3  # A, B and the sliver
    won, best, share = won_fractions(grouping.groups, occ, COUNTS, vote)
    frag = int(np.flatnonzero(vote.instance_group == 2)[0])
    a = int(np.flatnonzero(vote.instance_group == 0)[0])
    assert won[frag] < 0.1 and best[frag] == a and share[frag] > 0.9
    score_a = float(vote.scores[a])
    g2, v2 = absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(0.2, 0.1))
    assert len(v2.instance_group) == 2 and sorted(g2.groups) == [(0, 1, 2, 6, 7), (3, 4, 5)]
    (m,) = g2.merges
    assert m.stage == ABSORB_STAGE and m.a == (6, 7) and m.b == (0, 1, 2) and g2.events == (("merge", 0),)
    # the absorbing instance keeps its confidence (5 masks would have scored it above B)
    ka = int(np.flatnonzero([g2.groups[int(g)] == (0, 1, 2, 6, 7) for g in v2.instance_group])[0])
    assert v2.scores[ka] == pytest.approx(score_a) and list(v2.scores) == sorted(v2.scores, reverse=True)
    assert set(np.unique(v2.sv_label)) == {0, 1}  # the sliver went to A with the part masks


def test_off_and_guards_leave_the_vote_alone():
    grouping, vote, occ, s, revote = scenario()
    assert absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(0.0)) == (grouping, vote)
    # a fragment holding >= max_size_ratio of the absorber's points is a separate object
    g2, v2 = absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(0.2, 0.01))
    assert g2 is grouping and v2 is vote
    # masks that mostly lie on their own super-voxel: they won their footprint
    grouping, vote, occ, s, revote = scenario(frag_on_a=0.01, frag_sliver=1.0)
    won, _, _ = won_fractions(grouping.groups, occ, COUNTS, vote)
    assert np.nanmin(won) > 0.5
    assert absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(0.2, 0.1))[0] is grouping
    with pytest.raises(SceneError):
        RefineConfig(1.5)
    with pytest.raises(SceneError):
        RefineConfig(0.2, 0.0)


@settings(max_examples=30, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.05, 1.0), st.floats(0.0, 1.0))
def test_absorption_only_merges_and_keeps_every_labelled_supervoxel(on_a, sliver, th):
    grouping, vote, occ, s, revote = scenario(on_a, sliver)
    g2, v2 = absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(th, 1.0))
    # nodes are never lost or duplicated; every new group is a union of old ones
    assert sorted(i for g in g2.groups for i in g) == sorted(i for g in grouping.groups for i in g)
    assert all(any(set(o) <= set(g) for g in g2.groups) for o in grouping.groups)
    assert len(g2.merges) == len(grouping.groups) - len(g2.groups)
    assert np.array_equal(v2.sv_label >= 0, vote.sv_label >= 0)
    assert list(v2.scores) == sorted(v2.scores, reverse=True)


def test_a_group_unlike_its_neighbour_is_not_absorbed():
    """``absorb_min_semantic`` (session 10): the fragment's masks and A's have S_semantic 0.3."""
    grouping, vote, occ, s, revote = scenario()
    g_on, _ = absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(0.2, 0.1, absorb_min_semantic=0.25))
    assert len(g_on.merges) == 1 and g_on.merges[0].semantic == pytest.approx(0.3)
    g2, v2 = absorb_fragments(grouping, vote, occ, COUNTS, s, s, revote, RefineConfig(0.2, 0.1, absorb_min_semantic=0.35))
    assert g2 is grouping and v2 is vote
    # no semantic edge between the groups: no evidence against the merge, absorbed as before
    sem = s.copy()
    sem[np.ix_([6, 7], [0, 1, 2])] = np.nan
    sem[np.ix_([0, 1, 2], [6, 7])] = np.nan
    assert len(absorb_fragments(grouping, vote, occ, COUNTS, s, sem, revote,
                                RefineConfig(0.2, 0.1, absorb_min_semantic=0.9))[0].merges) == 1
    with pytest.raises(SceneError):
        RefineConfig(absorb_min_semantic=-0.1)
    from clutt3r_core.config import ADDED_AFTER_V1, PRESETS

    # off by default and for a stored config written before the field
    assert PRESETS["default"].refine.absorb_min_semantic == 0.0 == ADDED_AFTER_V1["refine.absorb_min_semantic"]


@settings(max_examples=25, deadline=None)
@given(st.floats(0.0, 1.0), st.floats(0.05, 1.0), st.lists(st.floats(-1.0, 1.0), min_size=64, max_size=64),
       st.floats(0.0, 1.0))
def test_every_absorption_clears_the_semantic_floor(on_a, sliver, sem, floor):
    grouping, vote, occ, s, revote = scenario(on_a, sliver)
    s_sem = np.asarray(sem, np.float32).reshape(8, 8)
    s_sem = np.where(np.isnan(s), np.nan, (s_sem + s_sem.T) / 2)
    g2, _ = absorb_fragments(grouping, vote, occ, COUNTS, s, s_sem, revote, RefineConfig(0.5, 1.0, absorb_min_semantic=floor))
    # (every cross pair of the scenario has an edge, so each merge records its mean)
    assert all(m.semantic >= floor - 1e-6 for m in g2.merges if m.stage == ABSORB_STAGE)


def test_pipeline_absorbs_fragments_and_the_trace_replays_them(tmp_path):
    from clutt3r_core.pipeline import PRESETS, instance_tree_json, segment
    from tests.core.test_pipeline import small_scene

    assert PRESETS["paper"].refine.min_won_fraction == 0.0 and PRESETS["default"].refine.min_won_fraction > 0
    # off in both: the grasp planner would count an object's own unlabelled flanks as foreign points
    assert PRESETS["paper"].refine.weak_echo_ratio == 0.0 and PRESETS["default"].refine.weak_echo_ratio == 0.0
    scene = small_scene(0, "harsh")
    # the absorption alone: the span rule (vote.span_cover) reads the absorbed groups, so with
    # the absorption off it acts on fragment groups too and the instance counts no longer subtract
    from dataclasses import replace

    cfg = replace(PRESETS["default"], vote=replace(PRESETS["default"].vote, span_cover=0.0))
    seg = segment(scene, cfg)
    tr = seg.trace
    absorbed = [m for m in tr.grouping.merges if m.stage == ABSORB_STAGE]
    assert absorbed  # this scene's harsh candidates leave part-mask groups (3 measured)
    # the replay of every event ends at the final groups, absorptions included
    assert {tuple(sorted(g)) for g in tr.groups_at(len(tr.grouping.events))} == {tuple(sorted(g)) for g in tr.grouping.groups}
    off = segment(scene, replace(cfg, refine=RefineConfig(0.0)))
    assert seg.num_instances == off.num_instances - len(absorbed)
    # leaves of an absorbed group are listed with the absorbing instance
    node_inst = tr.node_instance()
    for m in absorbed:
        assert len({int(node_inst[i]) for i in m.a + m.b}) == 1
    assert len(instance_tree_json(seg)["initial"]["leaf2inst"]) == int(tr.nodes.is_leaf.sum())
    # a saved run reads back with its absorptions and the same instances
    from clutt3r_core.pipeline import load_run, save_run

    back = load_run(save_run(seg, tmp_path / "run"))
    assert back.trace.config == seg.trace.config and np.array_equal(back.instance, seg.instance)
    assert [m.stage for m in back.trace.grouping.merges] == [m.stage for m in tr.grouping.merges]
    assert np.array_equal(back.trace.node_instance(), node_inst)


def _slab(counts_by_layer: dict[int, int], voxel: float = 0.005) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A 10 x 10 patch of voxels per z layer (normals +z); counts per layer."""
    pts, cnt = [], []
    for z, c in counts_by_layer.items():
        g = np.mgrid[0:10, 0:10].reshape(2, -1).T
        pts.append(np.column_stack([(g + 0.5) * voxel, np.full(len(g), (z + 0.5) * voxel)]))
        cnt.append(np.full(len(g), c))
    p = np.concatenate(pts)
    return p, np.tile([0.0, 0.0, 1.0], (len(p), 1)), np.concatenate(cnt)


def test_weak_echoes_are_the_sparse_flanks_of_a_dense_surface():
    from clutt3r_core.segmentation.refine import weak_echoes

    p, n, c = _slab({0: 2, 1: 3, 2: 40, 3: 4, 4: 30})  # flanks of 2-4 points around a 40-point layer
    e = weak_echoes(p, n, c, 0.005, 0.2)
    layer = np.round(p[:, 2] / 0.005 - 0.5).astype(int)
    assert e[layer == 0].all() and e[layer == 1].all() and e[layer == 3].all()
    assert not e[layer == 2].any() and not e[layer == 4].any()  # a second dense face 2 voxels away stays
    assert not weak_echoes(p, n, c, 0.005, 0.0).any()
    # normals the other way round find the same neighbours
    assert np.array_equal(weak_echoes(p, -n, c, 0.005, 0.2), e)
    # a lone sparse layer (a surface seen by one view) is not an echo of anything
    p1, n1, c1 = _slab({0: 3})
    assert not weak_echoes(p1, n1, c1, 0.005, 0.2).any()


@settings(max_examples=25, deadline=None)
@given(st.lists(st.integers(1, 60), min_size=5, max_size=5), st.floats(0.05, 0.9))
def test_the_densest_layer_is_never_an_echo(counts, ratio):
    from clutt3r_core.segmentation.refine import weak_echoes

    p, n, c = _slab(dict(enumerate(counts)))
    e = weak_echoes(p, n, c, 0.005, ratio)
    assert not e[c == max(counts)].any()
    assert not weak_echoes(p, n, c, 0.005, min(ratio, min(counts) / max(counts) * (1 - 1e-9))).any()  # no layer under it
