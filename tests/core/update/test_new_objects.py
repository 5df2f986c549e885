"""New objects enter the state (``ChangeConfig.new_objects``, ``update/newobj.py``): a mask of the
new view that no stored instance explains becomes an instance when the view has depth.
Tiny scenes: the boxes of ``_scenes.two_box_scene`` on a striped table; a third box that the
state never held appears in the new view (an object revealed by a grasp)."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st_
from scipy.spatial import cKDTree

from clutt3r_core.embeddings import AppearanceEmbedder
from clutt3r_core.scene import MaskCandidates, View
from clutt3r_core.update.newobj import next_instance_id, voxel_mean
from clutt3r_core.update.state import HistoryEntry, SceneState, apply_update, load_state, save_state
from clutt3r_core.update.types import ChangeConfig, UpdateResult
from clutt3r_core.update.update import update_scene

from ._scenes import box_points, camera, render_view, state_of, two_boxes_on_a_table
from .test_depth import CAM, FAST

NEW_BOX = dict(center=(0.0, 0.09, 0.02), size=(0.04, 0.04, 0.04),
               colors=[(230, 230, 40), (200, 200, 30), (240, 160, 200), (210, 130, 170), (250, 250, 120)])


def _with_new_box():
    """(state of two boxes on the table, points/colours/instances of the real scene with a third
    box (instance 2) behind them, the third box's points)."""
    pts, cols, inst = two_boxes_on_a_table()
    st = state_of(pts, cols, inst)
    p2, c2 = box_points(NEW_BOX["center"], NEW_BOX["size"], NEW_BOX["colors"])
    return (st, np.concatenate([pts, p2]), np.concatenate([cols, c2]),
            np.concatenate([inst, np.full(len(p2), 2, np.int32)]), p2)


def _visible(points: np.ndarray, v: View) -> np.ndarray:
    """The points the view's depth shows (within 1 cm)."""
    uv, z = v.camera.project(points.astype(np.float64))
    u, r = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
    ok = (u >= 0) & (u < v.camera.width) & (r >= 0) & (r < v.camera.height)
    d = np.full(len(points), np.nan)
    d[ok] = v.depth[r[ok], u[ok]]
    return points[np.abs(d - z) <= 0.01]


def test_a_revealed_object_becomes_a_new_instance_with_points_from_the_new_depth():
    st, pts, cols, inst, p2 = _with_new_box()
    v = render_view(pts, cols, inst, camera(**CAM))
    res = update_scene(st, v, FAST)
    assert [r.status for r in res.instances] == ["static", "static", "new"]
    rec = res.record(2)
    assert rec.match == "new-depth" and rec.mask_id == 3 and rec.T_world is None and rec.iou_after >= 0.7
    (a,) = res.added
    assert a.instance == 2 and a.mask_id == 3
    # every added point lies on the new box, and the points cover what the view shows of it
    assert np.max(cKDTree(p2).query(a.points)[0]) <= 0.006
    seen = _visible(p2, v)
    assert np.mean(cKDTree(a.points).query(seen)[0] <= 0.01) >= 0.9
    # voxel-downsampled like the state (one point per 5 mm cell)
    keys = np.floor(a.points / st.voxel_size).astype(np.int64)
    assert len(np.unique(keys, axis=0)) == len(a.points)
    # its embedding is its mask's, from the state's embedder
    e = AppearanceEmbedder().embed_masks(v.rgb, v.masks.masks[v.masks.ids == 3])[0]
    assert np.allclose(a.embedding, e / np.linalg.norm(e), atol=1e-5)
    doc = res.to_json()
    assert doc["instances"][-1]["status"] == "new" and doc["instances"][-1]["instance"] == 2
    assert {m["mask"]: m["instance"] for m in doc["new_masks"]} == {3: 2}


def test_the_next_update_treats_a_new_instance_like_any_other(tmp_path):
    st, pts, cols, inst, p2 = _with_new_box()
    v = render_view(pts, cols, inst, camera(**CAM))
    res = update_scene(st, v, FAST)
    st1 = apply_update(st, res)
    assert st1.instance_ids.tolist() == [0, 1, 2] and st1.history[-1].added == (2,)
    assert np.allclose(st1.embedding_of(2), res.added[0].embedding)
    save_state(st1, tmp_path / "s1", res)
    st1 = load_state(tmp_path / "s1")
    assert st1.history[-1].added == (2,) and np.count_nonzero(st1.instance == 2) == len(res.added[0].points)
    assert json.loads((tmp_path / "s1" / "update.json").read_text())["new_masks"][0]["instance"] == 2
    # the same view again: the new box is matched and static, nothing is added twice
    res2 = update_scene(st1, render_view(pts, cols, inst, camera(**CAM), frame=10), FAST)
    assert [(r.instance, r.status) for r in res2.instances] == [(0, "static"), (1, "static"), (2, "static")]
    assert res2.added == ()
    # then the new box is grasped: it is reported removed
    keep = inst != 2
    res3 = update_scene(st1, render_view(pts[keep], cols[keep], inst[keep], camera(**CAM), frame=11), FAST)
    assert res3.record(2).status == "removed" and res3.added == ()


def test_a_removed_id_is_never_reused():
    st, pts, cols, inst, p2 = _with_new_box()
    # update 1: box 1 (the highest id) is grasped
    keep = inst != 1
    gone = render_view(pts[keep & (inst != 2)], cols[keep & (inst != 2)], inst[keep & (inst != 2)], camera(**CAM))
    res1 = update_scene(st, gone, FAST)
    assert res1.record(1).status == "removed" and res1.added == ()
    st1 = apply_update(st, res1)
    assert st1.instance_ids.tolist() == [0] and next_instance_id(st1) == 2
    # update 2: the grasp revealed the third box
    res2 = update_scene(st1, render_view(pts[keep], cols[keep], inst[keep], camera(**CAM), frame=10), FAST)
    assert res2.by_status("new") == (2,)
    none = np.zeros((0, 4, 4))
    hist = (HistoryEntry(1, 8, (7,), (), none), HistoryEntry(2, 9, (), (), none, added=(9,)))
    assert next_instance_id(SceneState(st.points, st.colors, st.instance, st.instance_ids, st.embeddings,
                                       st.embedder, history=hist)) == 10


def test_without_depth_a_new_mask_is_reported_only():
    st, pts, cols, inst, p2 = _with_new_box()
    v = render_view(pts, cols, inst, camera(**CAM), with_depth=False)
    res = update_scene(st, v, FAST)
    assert res.by_status("new") == () and res.added == ()
    assert [(m.mask_id, m.instance) for m in res.new_masks] == [(3, -1)]
    assert apply_update(st, res).instance_ids.tolist() == [0, 1]


def test_new_objects_off_reports_only():
    st, pts, cols, inst, p2 = _with_new_box()
    v = render_view(pts, cols, inst, camera(**CAM))
    cfg = FAST.__class__(association=FAST.association, change=ChangeConfig(new_objects=False), pose=FAST.pose)
    res = update_scene(st, v, cfg)
    assert res.added == () and [(m.mask_id, m.instance) for m in res.new_masks] == [(3, -1)]


def test_masks_the_state_explains_or_that_show_the_table_are_not_added():
    pts, cols, inst = two_boxes_on_a_table()
    st = state_of(pts, cols, inst)
    v = render_view(pts, cols, inst, camera(**CAM))
    H, W = v.masks.shape
    table = np.zeros((H, W), bool)
    table[-30:, :60] = True  # a patch of bare table
    table &= ~v.masks.masks.any(axis=0)
    dup = np.roll(v.masks.masks[0], 2, axis=1)  # box 0 again, a 2-px shifted duplicate mask ...
    dup &= ~v.masks.masks[0]  # ... minus box 0's own mask: a rim, all of it explained by box 0 or the table
    dup |= v.masks.masks[1]  # a second mask of box 1 (a parent-like duplicate)
    v2 = View(v.frame, v.rgb, v.camera, v.depth,
              MaskCandidates(np.concatenate([v.masks.masks, table[None], dup[None]]),
                             np.concatenate([v.masks.ids, [7, 8]]).astype(np.int32)), v.name)
    res = update_scene(st, v2, FAST)
    assert res.by_status("static") == (0, 1) and res.added == ()


def test_update_result_needs_points_for_every_added_instance():
    import pytest

    from clutt3r_core.errors import SceneError
    from clutt3r_core.update.types import InstanceUpdate, NewInstance

    rec = InstanceUpdate(5, "new", None, 0.9, None, 3, "new-depth")
    res = UpdateResult(1, (rec,), (), np.zeros((1, 2, 2), bool), np.full((2, 2), -1, np.int32), 0.0)
    pts, cols, inst = two_boxes_on_a_table()
    st = state_of(pts, cols, inst)
    with pytest.raises(SceneError, match="must come with their points"):
        apply_update(st, res)
    with pytest.raises(SceneError, match="needs a record"):
        UpdateResult(1, (), (), np.zeros((0, 2, 2), bool), np.full((2, 2), -1, np.int32), 0.0,
                     added=(NewInstance(5, 3, np.zeros((1, 3)), np.zeros((1, 3), np.uint8)),))


@settings(max_examples=40, deadline=None)
@given(st_.integers(1, 300), st_.floats(0.002, 0.02), st_.integers(0, 10_000))
def test_voxel_mean_is_one_mean_per_occupied_cell(n, voxel, seed):
    rng = np.random.default_rng(seed)
    p = rng.uniform(-0.05, 0.05, (n, 3))
    c = rng.integers(0, 256, (n, 3)).astype(np.uint8)
    P, C = voxel_mean(p, c, voxel)
    keys = np.floor(p / voxel).astype(np.int64)
    cells = {tuple(k) for k in keys}
    assert len(P) == len(cells) == len(C)
    for q, col in zip(P, C):
        k = tuple(np.floor(q.astype(np.float64) / voxel).astype(np.int64))
        sel = np.all(keys == np.array(k), axis=1) if k in cells else None
        if sel is None:  # a float32 mean on a cell border: find the cell by nearest point
            sel = np.all(keys == keys[np.argmin(np.linalg.norm(p - q, axis=1))], axis=1)
        assert np.allclose(q, p[sel].mean(axis=0), atol=1e-6)
        assert np.all(np.abs(col.astype(int) - c[sel].mean(axis=0)) <= 0.5 + 1e-9)


def test_a_pushed_object_no_fit_explains_is_re_added_where_it_now_stands():
    # the registration cannot accept any fit (an IoU of 1 with the mask is out of reach) and no region is
    # searched: the pushed box's old place is empty, so it is reported removed; the mask the
    # association gave it is unmatched after all and shows what nothing stored explains: the box
    # comes back as a new instance at its new place (its old id stays removed, never reused)
    from .test_depth_regions import _pushed

    pts, cols, inst, st, c, T, moved = _pushed(25.0)
    v = render_view(moved, cols, inst, camera(**CAM), frame=8)
    cfg = FAST.__class__(association=FAST.association, pose=FAST.pose,
                         change=ChangeConfig(accept_iou=1.0, accept_iou_hidden=1.0, search_unexplained=False))
    res = update_scene(st, v, cfg)
    assert res.record(0).status == "removed" and res.record(1).status == "static"
    (a,) = res.added
    assert a.instance == 2 and a.mask_id == 1 and res.record(2).status == "new"
    assert np.max(cKDTree(moved[inst == 0]).query(a.points)[0]) <= 0.006
    assert np.mean(cKDTree(a.points).query(_visible(moved[inst == 0], v))[0] <= 0.01) >= 0.9
    st1 = apply_update(st, res)
    assert st1.instance_ids.tolist() == [1, 2] and next_instance_id(st1) == 3
