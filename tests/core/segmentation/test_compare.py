from __future__ import annotations

import pytest

from clutt3r_core.segmentation.compare import leaf_pair_agreement


def tree(entries):
    return {"schema_version": 1, "initial": {"initial_idx": [0, 1], "leaf2inst": [
        {"frame": f, "mask": m, "instance": i} for f, m, i in entries]}}


def test_identical_groupings_agree_fully_whatever_the_ids():
    a = tree([(0, 1, 0), (0, 2, 1), (1, 1, 0), (1, 2, 1)])
    b = tree([(0, 1, 7), (0, 2, 3), (1, 1, 7), (1, 2, 3)])
    r = leaf_pair_agreement(a, b)
    assert (r.precision, r.recall, r.f1) == (1.0, 1.0, 1.0)
    assert r.n_common == 4 and r.n_pairs_both == 2


def test_merged_pair_halves_precision_and_uncommon_leaves_are_ignored():
    ours = tree([(0, 1, 0), (0, 2, 0), (1, 1, 0), (1, 2, 0), (1, 9, 0)])
    ref = tree([(0, 1, 0), (0, 2, 1), (1, 1, 0), (1, 2, 1), (0, 5, 2)])
    r = leaf_pair_agreement(ours, ref)
    # common leaves: 4; ours says all 6 pairs are same, ref says 2
    assert r.n_common == 4 and r.n_ours == 5 and r.n_reference == 5
    assert r.precision == pytest.approx(2 / 6) and r.recall == 1.0
    assert r.f1 == pytest.approx(2 * (1 / 3) / (1 / 3 + 1))


def test_unassigned_leaves_are_never_same():
    a = tree([(0, 1, -1), (1, 1, -1)])
    b = tree([(0, 1, 0), (1, 1, 0)])
    r = leaf_pair_agreement(a, b)
    assert r.n_pairs_ours == 0 and r.recall == 0.0 and r.f1 == 0.0


def test_background_as_instance_is_a_second_reading_that_keeps_the_strict_one():
    ours = tree([(0, 1, 0), (1, 1, 0), (0, 2, -1), (1, 2, -1), (0, 3, -1)])
    ours["clutt3r"] = {"background_masks": [{"frame": 0, "mask": 2}, {"frame": 1, "mask": 2}]}
    ref = tree([(0, 1, 0), (1, 1, 0), (0, 2, 5), (1, 2, 5), (0, 3, 6)])
    strict = leaf_pair_agreement(ours, ref)
    assert strict.n_pairs_ours == 1 and strict.n_pairs_reference == 2 and strict.recall == 0.5
    support = leaf_pair_agreement(ours, ref, background_as_instance=True)
    # the two table masks count as "same" on our side; the unassigned (0, 3) still pairs with nothing
    assert support.n_pairs_ours == 2 and support.n_pairs_both == 2 and support.f1 == 1.0
    # a reference that splits the support (floor and wall) costs precision, as any merge would
    ref_split = tree([(0, 1, 0), (1, 1, 0), (0, 2, 5), (1, 2, 7), (0, 3, 6)])
    r = leaf_pair_agreement(ours, ref_split, background_as_instance=True)
    assert r.precision == 0.5 and r.recall == 1.0
    # without our extra key (e.g. the original's file on our side) nothing changes
    assert leaf_pair_agreement(ref, ref, background_as_instance=True).f1 == 1.0


def test_disagreeing_pairs_are_exactly_the_pairs_the_scores_miss():
    from clutt3r_core.segmentation.compare import disagreeing_pairs

    ours = tree([(0, 1, 0), (0, 2, 0), (1, 1, 0), (1, 2, 1), (1, 9, 0)])
    ref = tree([(0, 1, 0), (0, 2, 1), (1, 1, 0), (1, 2, 1), (0, 5, 2)])
    r = leaf_pair_agreement(ours, ref)
    d = disagreeing_pairs(ours, ref)
    assert sum(x.ours_same for x in d) == r.n_pairs_ours - r.n_pairs_both
    assert sum(not x.ours_same for x in d) == r.n_pairs_reference - r.n_pairs_both
    assert [(x.a, x.b, x.ours_same) for x in d] == [((0, 1), (0, 2), True), ((0, 2), (1, 1), True),
                                                    ((0, 2), (1, 2), False)]
