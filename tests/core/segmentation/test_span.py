"""Spanning candidate masks (``segmentation.span``, ours, session 9; off by default: the lead's held-out seeds lost AP@50)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.config import ADDED_AFTER_V1, PRESETS, SegmentConfig, config_from_json, config_to_json
from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.span import cleared_occupancy, span_revote, spanning_votes
from clutt3r_core.segmentation.vote import VoteConfig, supervoxel_vote

K = 8  # super-voxels 0-4: object A, 5-7: object B
COUNTS = np.full(K, 10)
NO_SUPPORT = np.zeros(K, bool)


def _occ(spanning: float = 1.0, b_occ: tuple[float, float] = (0.6, 0.6), a_covers_b: bool = False) -> np.ndarray:
    """Group A = masks 0, 1, 2 (mask 0 spans B's super-voxels), group B = masks 3, 4."""
    o = np.zeros((5, K), np.float32)
    o[0:3, 0:5] = 1.0
    o[0, 5:8] = spanning
    if a_covers_b:
        o[1:3, 5:8] = 1.0
    o[3, 5:8], o[4, 5:8] = b_occ
    return o


GROUPS = ((0, 1, 2), (3, 4))
ELIGIBLE = np.ones(2, bool)


def test_a_mask_spanning_another_group_is_found_and_cleared_there_only():
    s = spanning_votes(GROUPS, _occ(), COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5)
    assert s.node.tolist() == [0] and s.group.tolist() == [0] and s.spanned.tolist() == [1]
    assert s.cover[0] == pytest.approx(1.0) and s.confirm[0] == pytest.approx(0.0)
    assert s.cleared.tolist() == [[0, 5], [0, 6], [0, 7]]
    occ = cleared_occupancy(_occ(), s.cleared)
    assert (occ[0, 5:] == 0).all() and (occ[0, :5] == 1).all() and (occ[1:] == _occ()[1:]).all()


def test_no_mask_spans_when_off_when_its_group_confirms_it_or_on_support():
    assert len(spanning_votes(GROUPS, _occ(), COUNTS, NO_SUPPORT, ELIGIBLE, 0.0, 0.5).node) == 0
    # a whole-object group over a fragment of its own object: its other masks cover it too
    assert len(spanning_votes(GROUPS, _occ(a_covers_b=True), COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5).node) == 0
    support = np.zeros(K, bool)
    support[5:] = True  # B's super-voxels are table: no footprint
    assert len(spanning_votes(GROUPS, _occ(), COUNTS, support, ELIGIBLE, 0.5, 0.5).node) == 0
    # a group that does not vote (min_group_size) is never spanned
    assert len(spanning_votes(GROUPS, _occ(), COUNTS, NO_SUPPORT, np.array([True, False]), 0.5, 0.5).node) == 0
    # the spanning mask covers only 1 of B's 3 super-voxels: below a cover of 0.5
    o = _occ()
    o[0, 6:] = 0.0
    assert len(spanning_votes(GROUPS, o, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5).node) == 0


def test_the_spanned_object_gets_its_super_voxels_back_and_the_scores_stay():
    # session 9's rule: any voting group can be spanned, also one that won nothing
    cfg = dataclasses.replace(VoteConfig(), span_cover=0.5, span_instances_only=False)

    def vote_on(o):
        return supervoxel_vote(GROUPS, o, COUNTS, NO_SUPPORT, np.zeros((5, 5)), 5, cfg)

    # B's masks (0.55 + 0.4) lose to A's one spanning mask (1.0) on B's super-voxels
    weak_b = _occ(b_occ=(0.55, 0.4))
    before = vote_on(weak_b)
    a = int(np.flatnonzero(before.instance_group == 0)[0])
    assert (before.sv_label[5:] == a).all()
    # span_revote keeps each instance's confidence from the vote it gets (e.g. the absorption's)
    assert len(before.instance_group) == 1  # B won nothing: not an instance
    kept = dataclasses.replace(before, scores=np.array([0.9], np.float32))
    after = span_revote(GROUPS, weak_b, COUNTS, NO_SUPPORT, kept, vote_on, cfg)
    b_after = int(np.flatnonzero(after.instance_group == 1)[0])
    assert (after.sv_label[5:] == b_after).all() and (after.sv_label[:5] != b_after).all()
    assert after.span_cleared.tolist() == [[0, 5], [0, 6], [0, 7]]
    a_after = int(np.flatnonzero(after.instance_group == 0)[0])
    assert after.scores[a_after] == pytest.approx(0.9)  # kept; B's is its own (2 masks of 5 views)
    assert after.scores[b_after] == pytest.approx(2 / 5, abs=1e-2)
    assert (np.diff(after.scores) <= 0).all()


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.05, 1.0), st.floats(0.05, 1.0))
def test_cleared_pairs_are_unconfirmed_occupied_footprint_cells_and_shrink_with_the_cover(seed, cover, confirm):
    rng = np.random.default_rng(seed)
    u, k = 12, 20
    occ = np.where(rng.random((u, k)) < 0.4, rng.random((u, k)), 0.0).astype(np.float32)
    counts = rng.integers(1, 50, k)
    support = rng.random(k) < 0.2
    perm = rng.permutation(u)
    cuts = np.sort(rng.choice(np.arange(1, u), 3, replace=False))
    groups = tuple(tuple(sorted(p.tolist())) for p in np.split(perm, cuts) if len(p))
    eligible = rng.random(len(groups)) < 0.8
    s = spanning_votes(groups, occ, counts, support, eligible, cover, confirm)
    member = {n: gi for gi, m in enumerate(groups) for n in m}
    for node, sv in s.cleared.tolist():
        gi = member[node]
        assert eligible[gi] and not support[sv] and occ[node, sv] >= 0.5
        assert not any(occ[j, sv] >= 0.5 for j in groups[gi] if j != node)  # no other mask of its group
        spanned = s.spanned[s.node == node]
        assert any(occ[list(groups[b]), sv].sum() >= 0.5 for b in spanned)  # in a spanned footprint
    assert (s.cover >= cover).all() and (s.confirm < confirm).all() and (s.spanned != s.group).all()
    # a higher cover threshold clears a subset
    hi = spanning_votes(groups, occ, counts, support, eligible, min(1.0, cover + 0.2), confirm)
    assert {tuple(p) for p in hi.cleared.tolist()} <= {tuple(p) for p in s.cleared.tolist()}


def test_config_is_checked_and_old_configs_load_with_it_off(tmp_path):
    with pytest.raises(SceneError):
        VoteConfig(span_cover=-0.1)
    with pytest.raises(SceneError):
        VoteConfig(span_confirm=0.0)
    # on by default since session 10 (with its two guards), off in the paper preset
    v = SegmentConfig().vote
    assert (v.span_cover, v.span_instances_only, v.span_min_views) == (0.5, True, 0.5)
    assert PRESETS["paper"].vote.span_cover == 0.0
    data = config_to_json(SegmentConfig())
    for f in ("span_cover", "span_confirm", "span_occupancy", "span_instances_only", "span_min_views"):
        assert f"vote.{f}" in ADDED_AFTER_V1
        del data["vote"][f]
    old = config_from_json(data, tmp_path / "config.json").vote  # a config written before the rule: off
    assert old == dataclasses.replace(SegmentConfig().vote, span_cover=0.0, span_instances_only=False,
                                      span_min_views=0.0)


def test_a_run_with_the_rule_saves_its_cleared_pairs_and_explains_them(tmp_path, capsys):
    from clutt3r_core.commands.explain import explain_command
    from clutt3r_core.config import with_fields
    from clutt3r_core.explain import explain_supervoxel
    from clutt3r_core.pipeline import load_run, save_run, segment
    from clutt3r_core.synth import write_synth_scene

    from tests.core._tiny_run import tiny_scene

    scene = tiny_scene()
    # a low cover so that the tiny scene's masks span something (it has no under-segmented candidate)
    # session 9's rule, without the session-10 guards, so that the tiny scene has pairs to explain
    seg = segment(scene, with_fields(SegmentConfig(), {"vote.span_cover": 0.05, "vote.span_confirm": 1.0,
                                                       "vote.span_instances_only": False, "vote.span_min_views": 0.0}))
    sc = seg.trace.vote.span_cleared
    assert sc is not None and sc.ndim == 2 and sc.shape[1] == 2
    off = segment(scene, with_fields(SegmentConfig(), {"vote.span_cover": 0.0}))
    assert off.trace.vote.span_cleared is None
    d = tmp_path / "run"
    save_run(seg, d, scene_root=write_synth_scene(scene, tmp_path / "scene", contact_sheet=False))
    back = load_run(d)
    assert (back.trace.vote.span_cleared == sc).all() and (back.instance == seg.instance).all()
    assert len(sc)  # 101 pairs measured
    k = int(sc[0, 1])
    e = explain_supervoxel(back, k)
    assert int(sc[0, 0]) in [n for n, _ in e.span_cleared]
    explain_command(d, supervoxel=k)
    assert "did not vote here" in capsys.readouterr().out


def test_only_an_instance_can_be_spanned_by_default():
    """Session 10: clearing for a group that won nothing made it a second instance of an object."""
    cfg = dataclasses.replace(VoteConfig(), span_cover=0.5)
    assert cfg.span_instances_only
    weak_b = _occ(b_occ=(0.55, 0.4))

    def vote_on(o, counts=COUNTS):
        return supervoxel_vote(GROUPS, o, counts, np.zeros(o.shape[1], bool), np.zeros((5, 5)), 5, cfg)

    before = vote_on(weak_b)
    assert len(before.instance_group) == 1  # B won nothing: not an instance, so not spanned
    after = span_revote(GROUPS, weak_b, COUNTS, NO_SUPPORT, before, vote_on, cfg)
    assert after.span_cleared.shape == (0, 2)
    np.testing.assert_array_equal(after.sv_label, before.sv_label)
    # the same masks, but B also holds three super-voxels of its own (30 raw points): an instance
    occ = np.concatenate([weak_b, np.zeros((5, 3), np.float32)], axis=1)
    occ[3, K:] = 1.0
    counts = np.full(K + 3, 10)
    vote3 = lambda o: vote_on(o, counts)  # noqa: E731
    before = vote3(occ)
    assert len(before.instance_group) == 2
    b = int(np.flatnonzero(before.instance_group == 1)[0])
    assert (before.sv_label[5:K] != b).all()  # A's spanning mask took B's super-voxels 5-7
    after = span_revote(GROUPS, occ, counts, np.zeros(K + 3, bool), before, vote3, cfg)
    assert after.span_cleared.tolist() == [[0, 5], [0, 6], [0, 7]]
    b = int(np.flatnonzero(after.instance_group == 1)[0])
    assert (after.sv_label[5:] == b).all()


def test_spannable_restricts_the_spanned_groups_only():
    occ = _occ()
    every = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5)
    same = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, spannable=np.array([False, True]))
    none = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, spannable=np.array([True, False]))
    np.testing.assert_array_equal(same.cleared, every.cleared)
    assert len(every.cleared) and not len(none.cleared) and not len(none.node)
    with pytest.raises(SceneError, match="spannable"):
        spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, spannable=np.ones(3, bool))


def test_a_group_that_won_nothing_does_not_take_a_cleared_super_voxel():
    """Mask 5 (group C) beats B on super-voxel 5 once A's spanning mask is cleared; C won 20 raw
    points before (no instance), 30 with it: session 9's rule made C a new instance."""
    occ = np.concatenate([_occ(b_occ=(0.55, 0.4)), np.zeros((5, 5), np.float32)], axis=1)
    occ[3, K:K + 3] = 1.0  # B's own super-voxels 8-10: B is an instance
    occ = np.concatenate([occ, np.zeros((1, K + 5), np.float32)])
    occ[5, 5] = 0.96  # C: A's mask 0 (1.0) > C > B (0.95) on super-voxel 5
    occ[5, K + 3:] = 1.0
    groups = GROUPS + ((5,),)
    counts = np.full(K + 5, 10)
    no_support = np.zeros(K + 5, bool)

    def run(only: bool):
        cfg = dataclasses.replace(VoteConfig(), span_cover=0.5, span_instances_only=only)

        def vote_on(o):
            return supervoxel_vote(groups, o, counts, no_support, np.zeros((6, 6)), 5, cfg)

        before = vote_on(occ)
        assert sorted(before.instance_group.tolist()) == [0, 1]
        return span_revote(groups, occ, counts, no_support, before, vote_on, cfg)

    old, new = run(False), run(True)
    assert sorted(old.instance_group.tolist()) == [0, 1, 2]  # C became an instance
    assert sorted(new.instance_group.tolist()) == [0, 1]
    b = int(np.flatnonzero(new.instance_group == 1)[0])
    assert (new.sv_label[5:K + 3] == b).all()
    assert [5, 5] in new.span_cleared.tolist() and [5, 5] not in old.span_cleared.tolist()
    # what the trace records replays the vote (the viewer clears these pairs and votes again)
    cfg = dataclasses.replace(VoteConfig(), span_cover=0.5)
    replay = supervoxel_vote(groups, cleared_occupancy(occ, new.span_cleared), counts, no_support,
                             np.zeros((6, 6)), 5, cfg)
    np.testing.assert_array_equal(replay.sv_group, new.sv_group)


def test_a_group_with_few_views_does_not_span():
    """Session 10: with ``min_views`` the spanning mask's group needs other masks from that many views."""
    occ, view = _occ(), np.arange(5)  # group A: masks 0, 1, 2 in views 0, 1, 2
    base = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5)
    two = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, node_view=view, min_views=2)
    three = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, node_view=view, min_views=3)
    np.testing.assert_array_equal(two.cleared, base.cleared)  # mask 0's group: 2 other views
    assert not len(three.cleared)
    # two masks of one view (near-identical duplicates) count as one view
    dup = spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, node_view=np.array([0, 1, 1, 3, 4]),
                         min_views=2)
    assert not len(dup.cleared)
    with pytest.raises(SceneError, match="node_view"):
        spanning_votes(GROUPS, occ, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, min_views=2)
    # span_revote: ceil(share x views); 0.4 x 5 views = 2 other views needed, 0.5 x 5 -> 3
    for share, n in ((0.4, 3), (0.5, 0)):
        cfg = dataclasses.replace(VoteConfig(), span_cover=0.5, span_instances_only=False, span_min_views=share)

        def vote_on(o, cfg=cfg):
            return supervoxel_vote(GROUPS, o, COUNTS, NO_SUPPORT, np.zeros((5, 5)), 5, cfg)

        out = span_revote(GROUPS, occ, COUNTS, NO_SUPPORT, vote_on(occ), vote_on, cfg, view, 5)
        assert len(out.span_cleared) == n
    with pytest.raises(SceneError, match="span_min_views"):
        VoteConfig(span_min_views=1.5)


def _random_groups(rng):
    """A random (groups, occupancy, counts, support, eligible) set for the property tests: 12 masks
    in up to 4 groups over 20 super-voxels."""
    u, k = 12, 20
    occ = np.where(rng.random((u, k)) < 0.4, rng.random((u, k)), 0.0).astype(np.float32)
    counts = rng.integers(1, 50, k)
    support = rng.random(k) < 0.2
    cuts = np.sort(rng.choice(np.arange(1, u), 3, replace=False))
    groups = tuple(tuple(sorted(p.tolist())) for p in np.split(rng.permutation(u), cuts) if len(p))
    return groups, occ, counts, support, np.ones(len(groups), bool)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 4))
def test_the_guards_only_remove_pairs(seed, min_views):
    """Session 10's guards (spannable groups, minimum views) clear a subset of what the rule clears
    without them, and every pair they keep has a spanned group that may be spanned."""
    rng = np.random.default_rng(seed)
    groups, occ, counts, support, eligible = _random_groups(rng)
    u = occ.shape[0]
    view = rng.integers(0, 6, u)
    spannable = rng.random(len(groups)) < 0.6
    free = spanning_votes(groups, occ, counts, support, eligible, 0.3, 0.5)
    kept = spanning_votes(groups, occ, counts, support, eligible, 0.3, 0.5, spannable=spannable,
                          node_view=view, min_views=min_views)
    assert {tuple(p) for p in kept.cleared.tolist()} <= {tuple(p) for p in free.cleared.tolist()}
    assert spannable[kept.spanned].all()
    for node, gi in zip(kept.node.tolist(), kept.group.tolist()):
        assert len({int(view[j]) for j in groups[gi] if j != node}) >= min_views


def test_two_spanning_masks_do_not_confirm_each_other_with_confirm_apart():
    """Two views' masks of group A both cover B (under-segmented candidates): by default they confirm
    each other and nothing is cleared; with ``confirm_apart`` above their share of A's masks only A's
    masks that do not cover B themselves confirm, so both span B and are cleared there."""
    o = _occ()
    o[1, 5:8] = 1.0  # mask 1 of A spans B too; mask 2 stays on A only
    assert len(spanning_votes(GROUPS, o, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5).node) == 0
    # 2 of A's 3 masks span B: a majority, apart only from a share of 2/3
    assert len(spanning_votes(GROUPS, o, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, confirm_apart=0.6).node) == 0
    s = spanning_votes(GROUPS, o, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, confirm_apart=0.7)
    assert s.node.tolist() == [0, 1] and s.spanned.tolist() == [1, 1] and (s.confirm == 0).all()
    assert s.cleared.tolist() == [[0, 5], [0, 6], [0, 7], [1, 5], [1, 6], [1, 7]]
    # a third mask of A that covers only one of B's super-voxels (cover 1/3 < 0.5) still confirms there
    o2 = o.copy()
    o2[2, 5] = 1.0
    s2 = spanning_votes(GROUPS, o2, COUNTS, NO_SUPPORT, ELIGIBLE, 0.5, 0.5, confirm_apart=0.7)
    assert s2.cleared.tolist() == [[0, 6], [0, 7], [1, 6], [1, 7]]
    assert s2.confirm == pytest.approx([1 / 3, 1 / 3])
    assert SegmentConfig().vote.span_confirm_apart == 0.0  # off by default
    with pytest.raises(SceneError):
        VoteConfig(span_confirm_apart=1.5)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**31 - 1), st.floats(0.05, 1.0), st.floats(0.01, 1.0))
def test_confirm_apart_only_adds_pairs(seed, cover, apart):
    """Counting confirmation from fewer masks never confirms more: every pair the default clears is
    also cleared with ``confirm_apart``, and each pair's confirm share is not higher."""
    rng = np.random.default_rng(seed)
    groups, occ, counts, support, eligible = _random_groups(rng)
    u = occ.shape[0]
    base = spanning_votes(groups, occ, counts, support, eligible, cover, 0.5)
    apart = spanning_votes(groups, occ, counts, support, eligible, cover, 0.5, confirm_apart=apart)
    assert {tuple(p) for p in base.cleared.tolist()} <= {tuple(p) for p in apart.cleared.tolist()}
    by_pair = {(n, b): c for n, b, c in zip(apart.node.tolist(), apart.spanned.tolist(), apart.confirm.tolist())}
    for n, b, c in zip(base.node.tolist(), base.spanned.tolist(), base.confirm.tolist()):
        assert by_pair[(n, b)] <= c + 1e-6


def test_span_before_absorb_runs_on_a_tiny_scene_and_records_both_passes():
    """``span_before_absorb``: the pairs cleared before the absorption are kept in the trace with
    those after it (sorted, unique, each an occupied (node, super-voxel) pair), and they include
    at least the pairs the pre-absorption pass alone clears."""
    from clutt3r_core.config import with_fields
    from clutt3r_core.pipeline import segment

    from tests.core._tiny_run import tiny_scene

    scene = tiny_scene()
    loose = {"vote.span_cover": 0.05, "vote.span_confirm": 1.0, "vote.span_instances_only": False,
             "vote.span_min_views": 0.0, "refine.min_won_fraction": 0.0}
    pre_only = segment(scene, with_fields(SegmentConfig(), loose)).trace.vote.span_cleared  # no absorption
    seg = segment(scene, with_fields(SegmentConfig(), {**loose, "vote.span_before_absorb": True}))
    sc = seg.trace.vote.span_cleared
    assert len(pre_only) and sc.shape[1] == 2
    flat = sc[:, 0].astype(np.int64) * seg.trace.occupancy.shape[1] + sc[:, 1]
    assert (np.diff(flat) > 0).all()
    assert (seg.trace.occupancy[sc[:, 0], sc[:, 1]] > 0).all()
    assert {tuple(p) for p in pre_only.tolist()} <= {tuple(p) for p in sc.tolist()}
