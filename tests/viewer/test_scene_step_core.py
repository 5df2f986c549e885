"""The viewer shows the scene ``clutt3r query`` / ``clutt3r grasp --step`` see: both build it with
the core's ``update.scene_after.build_scene_after``, the viewer from the chain it loaded
(``scene_step.chain_inputs_of``: its ``UpdateFrame``s), the commands from the run folder
(``update.scene_after.chain_inputs``). The two readers give the same inputs value for value, so
the Grasps tab's request equals ``grasping.request.request_from_run``'s point for point, normal
for normal, including the added instance's PCA normals, oriented towards the camera of the post
view that added it and moved by a later update."""

from __future__ import annotations

import shutil

import numpy as np


def test_the_grasps_tab_plans_on_the_commands_request(tiny_run_dir, tiny_seg, tiny_scene, tmp_path):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import scene_grasp_request
    from tests.viewer._update_chain import build_chain

    v = tiny_scene.initial_views[0]
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run, frame=int(v.frame))  # update 1's post view is in the scene: a camera to face
    d = load_viewer_data(run)
    assert d.updates[0].camera is not None
    for step in (1, 2):  # the added instance as added, then pushed by update 2
        for i in (0, k):
            got = scene_grasp_request(d, step, i)
            want, _, _ = request_from_run(run, i, scene=tiny_run_dir.parent / "scene", step=step)
            assert got.instance == want.instance == i and got.views == want.views == ()
            np.testing.assert_array_equal(got.points, want.points)
            np.testing.assert_array_equal(got.normals, want.normals)
            np.testing.assert_array_equal(got.target, want.target)
            assert got.voxel_size == want.voxel_size and got.target.any()


def test_the_viewer_and_the_run_folder_give_the_builder_the_same_inputs(tiny_run_dir, tiny_seg, tiny_scene,
                                                                          tmp_path):
    """After each of the three updates (an instance added, pushed, removed) ``chain_inputs_of``
    (the viewer's loaded chain) equals ``chain_inputs`` (the run folder) field by field, and the
    scene the viewer shows is the core's ``SceneAfter`` at the displayed points."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_core.update.scene_after import build_scene_after, chain_inputs
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import chain_inputs_of, scene_after_of, shown_scene
    from tests.viewer._update_chain import build_chain

    v = tiny_scene.initial_views[0]
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run, frame=int(v.frame))
    d = load_viewer_data(run)
    eye = v.camera.T_world_camera[:3, 3]
    for step in range(4):
        got = chain_inputs_of(d, step)
        want = chain_inputs(run, step, seg=d.seg, eyes={int(v.frame): eye})
        for x in ("points", "colors", "normals", "instance", "ids", "added_points", "added_colors", "added_instance"):
            np.testing.assert_array_equal(getattr(got, x), getattr(want, x), err_msg=f"step {step}: {x}")
        assert got.num_ids == want.num_ids and got.n_updates == want.n_updates == 3
        assert len(got.history) == len(want.history) == step
        for hg, hw in zip(got.history, want.history):
            assert (hg.step, hg.frame, hg.removed, hg.displaced, hg.added) == \
                   (hw.step, hw.frame, hw.removed, hw.displaced, hw.added)
            np.testing.assert_array_equal(hg.T_world, hw.T_world)
        if step:  # the frame that added K faces its camera in both
            np.testing.assert_array_equal(got.eyes[int(v.frame)], want.eyes[int(v.frame)])
        sa, ref = scene_after_of(d, step), build_scene_after(want)
        for x in ("points", "normals", "instance", "present", "motions", "run_points", "gone"):
            np.testing.assert_array_equal(getattr(sa, x), getattr(ref, x), err_msg=f"step {step}: {x}")
        assert dict(sa.added) == dict(ref.added) and dict(sa.removed) == dict(ref.removed)
        sub = np.arange(0, len(tiny_seg.points), 5)
        sc = shown_scene(d, step, sub)
        np.testing.assert_array_equal(sc.points, ref.run_points[sub])
        np.testing.assert_array_equal(sc.instance, np.where(ref.gone, -1, ref.run_instance)[sub])
        if step:  # the colour layers' labels (Session.layer_input reads the loader's point_instance)
            np.testing.assert_array_equal(d.updates[step - 1].point_instance, np.where(ref.gone, -1, ref.run_instance))
        assert (k in sc.present.tolist()) == (step in (1, 2))


def test_the_query_tab_scores_the_scene_as_clutt3r_query_does(tiny_run_dir, tiny_seg, tiny_scene, tmp_path,
                                                                 monkeypatch):
    """After an update the Query tab ranks the instances of the scene shown with the scores of
    ``clutt3r query --step`` (``RunQuery.query_among``): the removed one is not scored and does not
    shift the others' (the name term is z-scored over the scene's instances only), the added one
    is described from its mask."""

    import clutt3r_core.query as cq
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_viewer.loading import load_viewer_data
    from tests.core.query._fake import FakeGrounder
    from tests.viewer._update_chain import build_chain, fake_query_panel

    v = tiny_scene.initial_views[0]
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run, frame=int(v.frame), mask=int(v.masks.ids[0]))
    d = load_viewer_data(run)
    panel, s, state = fake_query_panel(d, monkeypatch)
    rq = cq.RunQuery.open(run, grounder=FakeGrounder(), step=1, scene=tiny_run_dir.parent / "scene")
    for text in ("the red thing", "the blue thing", "yellow"):
        panel.run_query(s, text)
        want = rq.query(text)
        np.testing.assert_array_equal(state.query_scores, want.scores)
        assert state.query_best == want.target and np.isnan(want.scores[2]) and np.isfinite(want.scores[k])
        assert f"→ I{want.target} " + ("(confident)" if want.confident else "(_not confident") in panel.result.content


def test_a_corrected_chain_shows_the_commands_instances(tiny_run_dir, tiny_seg, tmp_path):
    """A merge made in the Edit tab before the update: the scene after it holds the corrected ids
    (the merged-away one is not an instance there) as ``update.scene_after`` does, and the Grasps
    tab's request on the merged instance (moved by the update, its merged fragment with it) is the
    command's."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_core.annotations import Annotations, Merge
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_core.update.scene_after import scene_after
    from clutt3r_core.update.state import apply_update, save_state, state_from_run
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import scene_grasp_request, shown_scene
    from tests.viewer.test_update_sources import _fake_update

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    counts = np.bincount(tiny_seg.instance[tiny_seg.instance >= 0], minlength=tiny_seg.num_instances)
    a, b = (int(k) for k in np.argsort(-counts)[:2])
    with Annotations.open(run, segmentation=tiny_seg, author="test") as ann:
        ann.apply_op(Merge(into=a, other=b))
    s0 = state_from_run(run)
    r1 = _fake_update(s0, 8, k=a, shift=0.05, removed=None, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    d = load_viewer_data(run, images=False)
    want = scene_after(run, 1)
    assert b not in want.present.tolist()
    np.testing.assert_array_equal(shown_scene(d, 1, np.arange(len(tiny_seg.points))).present, want.present)
    np.testing.assert_array_equal(d.updates[0].point_instance, np.where(want.gone, -1, want.run_instance))
    got, (req, _, _) = scene_grasp_request(d, 1, a), request_from_run(run, a, step=1)
    for x in ("points", "normals", "target"):
        np.testing.assert_array_equal(getattr(got, x), getattr(req, x))


def test_the_query_tab_ranks_a_split_off_instance_as_clutt3r_query_does(tiny_run_dir, tiny_seg, tiny_scene, tmp_path,
                                                                          monkeypatch):
    """A split made in the Edit tab before the update: the split-off id is an instance of the scene
    after it, ranked by the Query tab with the evidence ``clutt3r query --step`` gives it (its
    source's, ``query.corrected_evidence``), the same scores for every id."""
    import clutt3r_core.query as cq
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_core.annotations import Annotations, Split
    from clutt3r_core.update.state import apply_update, save_state, state_from_run
    from clutt3r_viewer.loading import load_viewer_data
    from tests.core.query._fake import FakeGrounder
    from tests.viewer._update_chain import fake_query_panel
    from tests.viewer.test_update_sources import _fake_update

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    counts = np.bincount(tiny_seg.instance[tiny_seg.instance >= 0], minlength=tiny_seg.num_instances)
    a = int(np.argmax(counts))
    pts = np.flatnonzero(tiny_seg.instance == a)
    half = pts[tiny_seg.points[pts, 0] < np.median(tiny_seg.points[pts, 0])]
    with Annotations.open(run, segmentation=tiny_seg, author="test") as ann:
        ann.apply_op(Split(points=tuple(half.tolist()), source=a))
    k = tiny_seg.num_instances  # the split-off id
    s0 = state_from_run(run)
    r1 = _fake_update(s0, 8, k=a, shift=0.05, removed=None, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    d = load_viewer_data(run)
    panel, s, state = fake_query_panel(d, monkeypatch)
    rq = cq.RunQuery.open(run, grounder=FakeGrounder(), step=1, scene=tiny_run_dir.parent / "scene")
    assert k in rq.scene.present.tolist()
    for text in ("the red thing", "the blue thing"):
        panel.run_query(s, text)
        want = rq.query(text)
        assert k in want.ranking and state.query_best == want.target, panel.result.content
        np.testing.assert_allclose(state.query_scores, want.scores, rtol=0, atol=1e-6)


def test_grasps_exported_after_an_update_record_the_step(tiny_run_dir, tiny_seg, tmp_path):
    """The Grasps tab's export of grasps planned in the scene after update 2 records ``"step": 2``
    in grasps.json, as ``clutt3r grasp --step 2`` does (a reader can tell where they were planned)."""
    import json
    import threading
    from types import SimpleNamespace

    import viser

    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.panels.grasps import GraspsPanel
    from clutt3r_viewer.scene_step import shown_scene
    from clutt3r_viewer.state import SessionState
    from tests.viewer._update_chain import build_chain
    from tests.viewer.conftest import free_port

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run)
    d = load_viewer_data(run, images=False)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    notes = []
    try:
        s = SimpleNamespace(client=server, lock=threading.RLock(), state=SessionState(),
                            app=SimpleNamespace(data=d, annotations=SimpleNamespace(run_dir=run)),
                            notify=lambda title, body: notes.append(body), scene_step=lambda: 2,
                            scene=lambda: shown_scene(d, 2, np.arange(len(d.seg.points))))
        p = GraspsPanel()
        p.build(s)
        p.plan_for(s, k)  # the added cube: graspable (test_scene_step)
        assert len(p._grasps) > 0, p.summary.content
        p._export(s)
        doc = json.loads((run / "grasps.json").read_text())
        assert doc["target"] == k and doc["step"] == 2 and "wrote" in notes[-1]
    finally:
        server.stop()
