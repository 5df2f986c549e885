"""The viewer reads a run's update chain (issue 10): Updates-tab frames and the pose replay."""

from __future__ import annotations

import shutil

import numpy as np

from clutt3r_core.update import InstanceUpdate, PoseResult, PoseTrace, UpdateResult
from clutt3r_core.update.state import apply_update, save_state, state_from_segmentation


def _fake_update(state, frame: int, k: int, shift: float, removed: int | None, n_iter: int) -> UpdateResult:
    """An update that moved instance k by ``shift`` m along x in n_iter recorded iterations."""
    Ts = np.tile(np.eye(4), (n_iter, 1, 1))
    Ts[:, 0, 3] = np.linspace(0.0, shift, n_iter)
    trace = PoseTrace(np.zeros(n_iter, np.int8), Ts, np.tile(np.linspace(1, 0.1, n_iter)[:, None], (1, 5)),
                      np.linspace(0.1, 0.9, n_iter))
    recs = []
    for i in state.instance_ids:
        i = int(i)
        if i == k:
            recs.append(InstanceUpdate(i, "displaced", 0.1, 0.9, Ts[-1], pose=PoseResult(Ts[-1], 0.1, 0.9, trace, 1, 0.0)))
        elif i == removed:
            recs.append(InstanceUpdate(i, "removed", None, None, None))
        else:
            recs.append(InstanceUpdate(i, "static", 0.9, 0.9, None))
    return UpdateResult(frame, tuple(recs), (), np.zeros((len(recs), 4, 4), bool), np.full((4, 4), -1, np.int32), 0.1)


def test_update_chain_is_replayed(tiny_run_dir, tiny_seg, tmp_path):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader and the source)
    from clutt3r_viewer.events import event_sources
    from clutt3r_viewer.loading import load_viewer_data

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    assert tiny_seg.num_instances >= 3
    s0 = state_from_segmentation(tiny_seg, run=run)
    r1 = _fake_update(s0, 8, k=0, shift=0.05, removed=2, n_iter=6)
    s1 = apply_update(s0, r1)
    save_state(s1, run / "updates" / "01_frame_000008", r1)
    r2 = _fake_update(s1, 9, k=0, shift=0.02, removed=None, n_iter=4)
    s2 = apply_update(s1, r2)
    save_state(s2, run / "updates" / "02_frame_000009", r2)

    d = load_viewer_data(run, images=False)
    assert [u.frame for u in d.updates] == [8, 9]
    assert "| 2 | removed |" in d.updates[0].text
    assert np.all(d.updates[1].point_instance[tiny_seg.instance == 2] == -1)  # removed stays removed
    src = [s for s in event_sources(d) if s.name == "scene updates: pose iterations"][0]
    assert src.num_events == 6 + 4
    idx = np.flatnonzero(tiny_seg.instance == 0)
    p0 = src.points(0, idx)
    np.testing.assert_allclose(p0, tiny_seg.points[idx], atol=1e-6)
    mid = src.points(6, idx)  # end of update 1: moved 5 cm
    np.testing.assert_allclose(mid[:, 0] - tiny_seg.points[idx, 0], 0.05, atol=1e-5)
    last = src.points(src.num_events, idx)  # both updates composed: the final state's points
    np.testing.assert_allclose(last, s2.points[s2.instance == 0], atol=1e-5)
    assert "iteration" in src.text(3)

    # the rerun export writes the same chain (pose iterations on their own timeline)
    import rerun as rr

    from clutt3r_viewer.panels.update_sources import export_updates_rerun

    rec = rr.RecordingStream("clutt3r-test")
    rec.save(tmp_path / "u.rrd")
    assert export_updates_rerun(rec, d) == src.num_events
    rec.flush()
    rec.disconnect()
    assert (tmp_path / "u.rrd").stat().st_size > 1000


def test_update_curves_hold_the_last_value(tiny_seg):
    from clutt3r_core.update import UpdateFrame
    from clutt3r_viewer.panels.update_sources import update_curves

    s0 = state_from_segmentation(tiny_seg)
    res = _fake_update(s0, 8, k=1, shift=0.02, removed=None, n_iter=7)
    x, loss, iou, ids = update_curves(UpdateFrame(frame=8, result=res))
    assert ids == (1,) and x.shape == (7,) and loss.shape == iou.shape == (1, 7)
    np.testing.assert_allclose(iou[0], np.linspace(0.1, 0.9, 7))
    assert update_curves(UpdateFrame(frame=8))[3] == ()


def _chain(tiny_run_dir, tiny_seg, tmp_path):
    """Run copy with two saved updates: 1 moves instance 0 by 5 cm and removes 2, 2 moves 0 by 2 cm
    more and turns instance 1 by 90 deg about its centroid (z)."""
    from clutt3r_viewer.loading import load_viewer_data

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    s0 = state_from_segmentation(tiny_seg, run=run)
    r1 = _fake_update(s0, 8, k=0, shift=0.05, removed=2, n_iter=6)
    s1 = apply_update(s0, r1)
    save_state(s1, run / "updates" / "01_frame_000008", r1)
    r2 = _fake_update(s1, 9, k=0, shift=0.02, removed=None, n_iter=4)
    c = tiny_seg.points[tiny_seg.instance == 1].mean(axis=0)
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = c - T[:3, :3] @ c
    recs = tuple(r if r.instance != 1 else InstanceUpdate(1, "displaced", 0.2, 0.8, T) for r in r2.instances)
    r2 = UpdateResult(r2.frame, recs, r2.new_masks, r2.change_masks, r2.projected, r2.time_s)
    s2 = apply_update(s1, r2)
    save_state(s2, run / "updates" / "02_frame_000009", r2)
    return load_viewer_data(run, images=False), s1, s2


def test_updated_scene_moves_displaced_instances_along_the_chain(tiny_run_dir, tiny_seg, tmp_path):
    """The Updates tab's scene: after update u = the saved state u's points (poses composed along
    the chain), before update u = after update u - 1; removed instances are 'gone' from then on."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_viewer.scene_step import scene_after_of, scene_step, shown_scene

    d, s1, s2 = _chain(tiny_run_dir, tiny_seg, tmp_path)
    idx = np.arange(len(tiny_seg.points))

    def updated_scene(u: int, after: bool = True):  # the tab's scene for its (update u, after) choice
        sc = shown_scene(d, scene_step(u, after, len(d.updates)), idx)
        return sc.points, sc.instance, sc.gone

    inst0 = tiny_seg.instance
    p_init, lab, gone = updated_scene(-1)
    np.testing.assert_array_equal(p_init, tiny_seg.points)
    assert not gone.any() and np.array_equal(lab, inst0)
    for u, st in ((0, s1), (1, s2)):
        pts, lab, gone = updated_scene(u, after=True)
        for k in (0, 1):  # every kept instance's points are the saved state's (float32 there)
            np.testing.assert_allclose(pts[inst0 == k], st.points[st.instance == k], atol=1e-5)
        assert np.all(gone == (inst0 == 2)) and np.all(lab[inst0 == 2] == -1)
    # before update 1 = after update 0: instance 0 moved 5 cm, instance 1 not yet turned
    before, _, _ = updated_scene(1, after=False)
    after0, _, _ = updated_scene(0, after=True)
    np.testing.assert_array_equal(before, after0)
    np.testing.assert_allclose(before[inst0 == 0, 0] - tiny_seg.points[inst0 == 0, 0], 0.05, atol=1e-9)
    np.testing.assert_array_equal(before[inst0 == 1], tiny_seg.points[inst0 == 1])
    after1, _, _ = updated_scene(1, after=True)
    np.testing.assert_allclose(after1[inst0 == 0, 0] - tiny_seg.points[inst0 == 0, 0], 0.07, atol=1e-9)
    assert np.abs(after1[inst0 == 1] - tiny_seg.points[inst0 == 1]).max() > 0.001  # turned
    M = [scene_after_of(d, step).motions for step in range(3)]  # the composed motions the points were moved by
    assert M[2].shape == (tiny_seg.num_instances, 4, 4) and np.allclose(M[0], np.eye(4))
    np.testing.assert_allclose(M[2][0, 0, 3], 0.07)


def test_update_layer_ghosts_removed_instances(tiny_run_dir, tiny_seg, tmp_path):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the layer)
    from clutt3r_viewer.data import label_colors
    from clutt3r_viewer.layers import LayerInput, layer_named
    from clutt3r_viewer.panels.update_sources import GHOST_WHITE, UpdateSceneLayer
    from clutt3r_viewer.state import SessionState

    d, _, _ = _chain(tiny_run_dir, tiny_seg, tmp_path)
    layer = layer_named("update")
    assert isinstance(layer, UpdateSceneLayer)
    idx = np.arange(len(tiny_seg.points))
    inp = LayerInput(d, idx, tiny_seg.instance, np.ones(tiny_seg.num_instances, np.float32))
    st = SessionState(update=0, update_after=True)
    col = layer.colors(inp, st)
    own = label_colors(tiny_seg.instance)
    gone = tiny_seg.instance == 2
    ghost = np.round((1 - GHOST_WHITE) * own[gone].astype(np.float32) + GHOST_WHITE * 255).astype(np.uint8)
    np.testing.assert_array_equal(col[gone], ghost)
    np.testing.assert_array_equal(col[~gone], own[~gone])
    st.update_after = False  # before update 0: the initial segmentation's colours
    np.testing.assert_array_equal(layer.colors(inp, st), own)


def test_update_frames_take_the_post_view_camera_update_json_records(tiny_run_dir, tiny_seg, tiny_scene, tmp_path):
    """An update that records its post view's camera (update.json "camera", session 8) has it in
    the viewer without the scene folder (an ``--image`` update has no view there); one written
    before (no "camera") has none, as before."""
    from dataclasses import replace

    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_viewer.loading import load_viewer_data

    cam = tiny_scene.initial_views[0].camera
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    s0 = state_from_segmentation(tiny_seg, run=run)
    r1 = replace(_fake_update(s0, 8, k=0, shift=0.05, removed=None, n_iter=3), camera=cam)
    s1 = apply_update(s0, r1)
    save_state(s1, run / "updates" / "01_frame_000008", r1)
    r2 = _fake_update(s1, 9, k=0, shift=0.02, removed=None, n_iter=3)  # as written before session 8
    save_state(apply_update(s1, r2), run / "updates" / "02_frame_000009", r2)

    d = load_viewer_data(run, images=False)
    got = d.updates[0].camera
    np.testing.assert_array_equal(got.K, cam.K)
    np.testing.assert_array_equal(got.T_world_camera, cam.T_world_camera)
    assert d.updates[0].result.change_masks.shape[1:] == (cam.height, cam.width)
    assert d.updates[1].camera is None
