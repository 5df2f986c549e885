"""The Explain tab's and the Replay highlight's pure parts (no browser)."""

from __future__ import annotations

import numpy as np

from clutt3r_core.explain import explain_pair
from clutt3r_viewer.panels.explain import as_markdown, mask_at_supervoxel
from clutt3r_viewer.panels.replay import COLOUR_A, COLOUR_B, pair_image, step_groups


def test_mask_at_supervoxel_prefers_the_selected_view(tiny_data):
    d = tiny_data
    tr = d.trace
    n = tr.nodes
    k = int(np.argmax((tr.occupancy[n.is_leaf & ~n.background] > 0).sum(0)))  # seen by the most leaves
    i = mask_at_supervoxel(d, k)
    assert i >= 0 and tr.occupancy[i, k] == tr.occupancy[(n.is_leaf | d.substituted) & ~n.background, k].max()
    for vi in range(len(tr.frames)):
        j = mask_at_supervoxel(d, k, vi)
        here = (n.view == vi) & n.is_leaf & ~n.background & (tr.occupancy[:, k] > 0)
        assert (n.view[j] == vi) == bool(here.any())
    assert mask_at_supervoxel(d, int(np.flatnonzero(tr.occupancy.max(0) == 0)[0])) == -1 \
        if (tr.occupancy.max(0) == 0).any() else True


def test_step_groups_follow_the_events(tiny_data):
    d = tiny_data
    g = d.trace.grouping
    assert step_groups(d, 0) is None and step_groups(d, len(g.events) + 1) is None
    kind, idx = g.events[0]
    a, b, words = step_groups(d, 1)
    if kind == "merge":
        assert (a, b) == (g.merges[idx].a, g.merges[idx].b) and f"{g.merges[idx].score:.3f}" in words


def test_pair_image_tints_a_orange_and_b_blue(tiny_data):
    d = tiny_data
    n = d.trace.nodes
    a = int(next(i for i in d.view_nodes(0) if n.is_leaf[i] and not n.background[i]))
    b = int(next(i for i in d.view_nodes(1) if n.is_leaf[i] and not n.background[i]))
    img = pair_image(d, (a,), (b,))
    h, w = d.views[0].rgb.shape[:2]
    assert img.shape[1] <= 480 + 4 and img.shape[2] == 3
    tile = img.shape[1] // 2
    step = -(-w // (480 // 2))
    ma = d.node_mask(a)[::step, ::step]
    left = img[: ma.shape[0], : ma.shape[1]].astype(int)
    assert np.abs(left[ma] - COLOUR_A).sum(-1).mean() < np.abs(left[ma] - COLOUR_B).sum(-1).mean()
    assert tile > 0


def test_markdown_of_an_explanation(tiny_data):
    tr = tiny_data.trace
    n = tr.nodes
    leaves = np.flatnonzero(n.is_leaf & ~n.background)
    e = explain_pair(tr, int(leaves[0]), int(leaves[-1]))
    md = as_markdown(e.text())
    assert md.startswith("**masks ") and "  \n" in md and "tau_spat" in md


def test_tree_image_draws_one_row_per_mask_and_marks_the_selection(tiny_data):
    from clutt3r_viewer.panels.tree import ROLE_COLOURS, ROW, THUMB, node_kind, tree_image, tree_order

    d = tiny_data
    order = tree_order(d, 0)
    plain = tree_image(d, 0)
    assert plain.shape == (ROW * len(order) + 4, 480, 3) and plain.dtype == np.uint8
    for r, (i, depth) in enumerate(order):  # the frame of each thumbnail is its role's colour
        x0, y0 = 4 + depth * 28, 2 + r * ROW
        assert tuple(plain[y0 + THUMB // 2, x0]) == ROLE_COLOURS[node_kind(d, i)]
    i, _ = order[-1]
    sel = tree_image(d, 0, i)
    y = 2 + (len(order) - 1) * ROW
    assert tuple(sel[y, 470]) == (255, 236, 150) and tuple(plain[y, 470]) == (250, 250, 250)
