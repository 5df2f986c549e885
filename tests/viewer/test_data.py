"""clutt3r_viewer.data: derivations from a run, checked against the trace they come from."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_viewer.data import PALETTE, event_text, label_colors, lod_indices, ramp_colors


@given(n=st.integers(0, 5000), m=st.integers(-1, 6000), seed=st.integers(0, 3))
@settings(max_examples=60, deadline=None)
def test_lod_indices_is_a_sorted_unique_subset_of_the_right_size(n, m, seed):
    idx = lod_indices(n, m, seed)
    assert len(idx) == (n if m <= 0 else min(n, m))
    assert np.all(np.diff(idx) > 0)
    assert len(idx) == 0 or (idx[0] >= 0 and idx[-1] < n)
    assert np.array_equal(idx, lod_indices(n, m, seed))  # deterministic


def test_label_and_ramp_colours():
    c = label_colors(np.array([-1, 0, 1, 64]))
    assert c.dtype == np.uint8 and c.shape == (4, 3)
    assert np.array_equal(c[1], PALETTE[0]) and np.array_equal(c[3], PALETTE[0])
    assert not np.array_equal(c[1], c[2])
    r = ramp_colors(np.array([0.0, 1.0, np.nan]))
    assert r[0, 2] > r[0, 0] and r[1, 0] > r[1, 2]  # blue at the low end, red at the high end
    assert len(np.unique(PALETTE, axis=0)) == len(PALETTE)


def test_replay_ends_at_the_final_vote(tiny_data):
    d = tiny_data
    tr, seg = d.trace, d.seg
    final = d.replay_sv_group(d.num_events)
    first = np.array([tr.grouping.groups[g][0] for g in tr.vote.instance_group] or [], np.int64)
    expect = np.where(tr.vote.sv_label >= 0, first[np.maximum(tr.vote.sv_label, 0)] if len(first) else -1, -1)
    assert np.array_equal(final, expect)
    assert d.replay_num_groups(d.num_events) == len(tr.grouping.groups)
    assert d.replay_num_groups(0) == int((tr.nodes.is_leaf & ~tr.nodes.background).sum())
    # every merge removes one group; a substitution replaces >=1 residuals by one parent
    counts = [d.replay_num_groups(n) for n in range(d.num_events + 1)]
    assert all(b <= a for a, b in zip(counts, counts[1:]))
    assert seg.num_instances == len(np.unique(final[final >= 0]))


def test_edges_join_leaves_of_different_views_only(tiny_data):
    d = tiny_data
    n = d.trace.nodes
    assert len(d.edges) > 0
    assert np.all(d.edges[:, 0] < d.edges[:, 1])
    assert np.all(n.view[d.edges[:, 0]] != n.view[d.edges[:, 1]])
    assert np.all(n.is_leaf[d.edges].all(axis=1) & ~n.background[d.edges].any(axis=1))
    assert np.allclose(d.edge_spatial, d.trace.s_spatial[d.edges[:, 0], d.edges[:, 1]], equal_nan=True)
    i = int(d.edges[0, 0])
    nb = d.neighbours(i)
    sp = [np.nan_to_num(x[1], nan=-1) for x in nb]
    assert sp == sorted(sp, reverse=True)
    assert {j for j, *_ in nb} == set(d.edges[d.edges[:, 0] == i, 1]) | set(d.edges[d.edges[:, 1] == i, 0])


def test_node_geometry_and_roles(tiny_data):
    d = tiny_data
    tr = d.trace
    u = len(tr.nodes)
    assert d.node_centroid.shape == (u, 3)
    lo, hi = d.seg.points.min(0) - 1e-6, d.seg.points.max(0) + 1e-6
    ok = np.isfinite(d.node_centroid[:, 0])
    assert np.all((d.node_centroid[ok] >= lo) & (d.node_centroid[ok] <= hi))
    for k in range(d.seg.num_instances):
        for i in d.seg.instance_nodes(k):
            assert d.node_instance[i] == k
    i = int(np.flatnonzero(ok)[0])
    assert d.node_points(i).sum() > 0
    assert d.node_mask(i).shape == (d.views[0].camera.height, d.views[0].camera.width)


def test_event_text_names_each_event(tiny_data):
    tr = tiny_data.trace
    assert "start" in event_text(tr, 0)
    for n in range(1, tiny_data.num_events + 1):
        kind, _ = tr.grouping.events[n - 1]
        assert kind in event_text(tr, n) and f"{n}/{tiny_data.num_events}" in event_text(tr, n)


def test_text_scores_rank_instances_by_their_masks(tiny_data):
    from tests.viewer.conftest import FakeTextEmbedder

    emb = FakeTextEmbedder().embed_text(["red"])[0]
    s = tiny_data.instance_text_scores(emb)
    assert s.shape == (tiny_data.seg.num_instances,)
    cos = tiny_data.trace.embeddings @ emb
    k = int(np.argmax(s))
    assert np.isclose(s[k], cos[list(tiny_data.seg.instance_nodes(k))].max(), atol=1e-5)


def test_node_highlight_ignores_super_voxels_the_mask_barely_touches(tiny_data):
    # A leaf whose mask bleeds a few pixels onto the table must not light up the table: only
    # super-voxels it covers at least the vote's min_coverage of are highlighted.
    d = tiny_data
    occ = d.trace.occupancy
    thr = d.trace.config.vote.min_coverage
    rows = [i for i in range(len(occ)) if (occ[i] >= thr).any() and ((occ[i] > 0) & (occ[i] < thr)).any()]
    assert rows, "the tiny scene should have a mask that only grazes some super-voxel"
    i = rows[0]
    pts = d.node_points(i)
    grazed = (occ[i] > 0) & (occ[i] < thr)
    assert not pts[grazed[d.seg.sv_labels]].any()
    assert pts[(occ[i] >= thr)[d.seg.sv_labels]].all()
