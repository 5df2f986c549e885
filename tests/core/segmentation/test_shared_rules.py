"""Rules with one home, used by the pipeline and the baselines alike: background masks, minimum mask
area, instance renumbering by score, node -> instance."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from clutt3r_core.baselines.common import mask_evidence
from clutt3r_core.occupancy import VoxelHits
from clutt3r_core.pipeline import instance_tree_json
from clutt3r_core.segmentation.evidence import background_masks
from clutt3r_core.segmentation.trees import TreeConfig, min_mask_area
from clutt3r_core.segmentation.vote import renumber_by_score

from .._tiny_run import tiny_scene, tiny_segmentation


def test_background_rule_cases():
    support = np.array([True, True, False, False])
    hits = VoxelHits.from_dense(np.array([
        [5, 3, 0, 0],    # all on support -> background
        [2, 0, 2, 0],    # exactly half: not more than 0.5 -> object
        [0, 0, 0, 0],    # no 3D evidence at all -> background
        [1, 0, 10, 0],   # one stray support pixel against ten object pixels -> object (pixel-weighted)
        [3, 0, 1, 0],    # mostly on support -> background
    ], np.float32))
    np.testing.assert_array_equal(background_masks(hits, support, 0.5), [True, False, True, False, True])
    assert background_masks(VoxelHits.from_dense(np.zeros((0, 4))), support, 0.5).shape == (0,)


def test_pipeline_and_baselines_agree_on_background_masks():
    seg, ev = tiny_segmentation(), mask_evidence(tiny_scene())
    n = seg.trace.nodes
    ours = {(int(n.view[i]), int(n.mask_id[i])): bool(n.background[i]) for i in range(len(n))}
    theirs = {(int(v), int(m)): bool(b) for v, m, b in zip(ev.view, ev.mask_id, ev.background)}
    assert ours == theirs  # same masks kept (min_mask_area) and the same background verdicts
    assert any(ours.values()) and not all(ours.values())


def test_min_mask_area():
    assert min_mask_area(TreeConfig(min_area_px=7), 480, 640) == 7
    assert min_mask_area(TreeConfig(), 480, 640) == 31  # 0.01 % of 307200 px
    assert min_mask_area(TreeConfig(), 10, 10) == 1


@settings(max_examples=80, deadline=None)
@given(
    g=st.integers(0, 8),
    data=st.data(),
)
def test_renumber_by_score(g, data):
    score = data.draw(hnp.arrays(np.float64, g, elements=st.sampled_from([0.0, 0.5, 1.0, 2.0])))
    keep = data.draw(hnp.arrays(bool, g))
    label = data.draw(hnp.arrays(np.int64, 20, elements=st.integers(-1, max(g - 1, -1))))
    new, order = renumber_by_score(label, score, keep)
    k = int(keep.sum())
    assert sorted(order.tolist()) == np.flatnonzero(keep).tolist()
    # descending score, lower group first on ties
    assert all((score[a], -a) > (score[b], -b) for a, b in zip(order[:-1], order[1:]))
    for old, nw in zip(label, new):
        if old < 0 or not keep[old]:
            assert nw == -1
        else:
            assert 0 <= nw < k and order[nw] == old
    assert new.dtype == np.int32


def test_node_instance_matches_groups_and_the_instance_tree():
    seg = tiny_segmentation()
    tr = seg.trace
    plain = tr.node_instance()
    for k in range(seg.num_instances):
        assert set(np.flatnonzero(plain == k)) == set(seg.instance_nodes(k))
    followed = tr.node_instance(follow_substitutions=True)
    for s in tr.grouping.substitutions:
        assert all(followed[r] == followed[s.parent] for r in s.replaced)
    changed = np.flatnonzero(plain != followed)
    assert set(changed) <= {r for s in tr.grouping.substitutions for r in s.replaced}
    leaf2inst = {(e["frame"], e["mask"]): e["instance"] for e in instance_tree_json(seg)["initial"]["leaf2inst"]}
    n = tr.nodes
    assert leaf2inst == {n.key(i): int(followed[i]) for i in np.flatnonzero(n.is_leaf)}
