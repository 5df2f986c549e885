"""The scene after the updates shown (``clutt3r_viewer.scene_step``): the instances an update added
are in it (with their points, colours, embedding), moved by later updates and gone once removed;
the timeline says what each update did; the pose replay carries the added instances; a grasp can
be planned on an added instance; every colour layer colours them."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from tests.viewer._update_chain import N_ITER, NEW_RGB, SHIFT_0, SHIFT_K, build_chain, fake_query_panel, new_points


@pytest.fixture(scope="module")
def chain(tiny_run_dir, tiny_seg, tmp_path_factory):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_viewer.loading import load_viewer_data

    run = tmp_path_factory.mktemp("chain") / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run)
    return load_viewer_data(run, images=False), k


def test_the_scene_after_each_update(chain, tiny_seg):
    from clutt3r_viewer.scene_step import scene_step, shown_scene

    d, k = chain
    assert k == tiny_seg.num_instances  # a fresh id, after the run's
    cases = ((-1, True), (0, False), (0, True), (2, False), (2, True))
    assert [scene_step(u, a, 3) for u, a in cases] == [0, 0, 1, 2, 3]
    idx = np.arange(len(tiny_seg.points))
    pts = new_points(tiny_seg)
    s0 = shown_scene(d, 0, idx)
    assert not s0.moved and len(s0.added_points) == 0 and s0.present.tolist() == list(range(tiny_seg.num_instances))
    np.testing.assert_array_equal(s0.points, tiny_seg.points)

    s1 = shown_scene(d, 1, idx)
    assert k in s1.present.tolist() and 2 not in s1.present.tolist() and s1.removed == (2,)
    assert s1.added_in == {k: 8}
    np.testing.assert_allclose(s1.added_points, pts, atol=1e-6)
    assert np.all(s1.added_instance == k) and np.all(s1.added_colors == NEW_RGB)
    was0 = tiny_seg.instance == 0
    np.testing.assert_allclose(s1.points[was0] - tiny_seg.points[was0], [[SHIFT_0, 0, 0]] * int(was0.sum()), atol=1e-6)
    assert np.array_equal(s1.gone, tiny_seg.instance == 2) and np.all(s1.instance[s1.gone] == -1)

    s2 = shown_scene(d, 2, idx)  # the added instance moved by the next update
    np.testing.assert_allclose(s2.added_points - pts, [[SHIFT_K, 0, 0]] * len(pts), atol=1e-6)
    s3 = shown_scene(d, 3, idx)  # and removed by the third
    assert len(s3.added_points) == 0 and k not in s3.present.tolist() and s3.removed == (2, k)
    sub = idx[::7]  # the level of detail: the same scene for fewer points
    np.testing.assert_allclose(shown_scene(d, 1, sub).points, s1.points[::7])


def test_the_timeline_says_what_each_update_did(chain):
    from clutt3r_viewer.panels.updates import timeline_markdown
    from clutt3r_viewer.scene_step import chain_steps

    d, k = chain
    s1, s2, s3 = chain_steps(d)
    assert (s1.frame, s1.removed, s1.added) == (8, (2,), (k,))
    ((i, move, turn),) = s1.displaced
    assert i == 0 and move == pytest.approx(SHIFT_0, abs=1e-6) and turn == pytest.approx(0.0, abs=1e-4)
    assert s2.displaced[0][0] == k and s2.displaced[0][1] == pytest.approx(SHIFT_K, abs=1e-6) and not s2.added
    assert s3.removed == (k,)
    md = timeline_markdown(chain_steps(d), 2)
    lines = md.split("\n")
    assert f"1 · frame 8: removed I2; displaced I0 (5.0 cm, 0°); _new_ I{k}" in md
    assert sum("▶" in ln for ln in lines) == 1 and "▶ 2 · frame 9" in md and f"removed I{k}" in lines[-1]


def test_the_pose_replay_carries_the_added_instances(chain, tiny_seg):
    from clutt3r_viewer.events import event_sources

    d, k = chain
    src = next(s for s in event_sources(d) if s.name == "scene updates: pose iterations")
    assert src.num_events == sum(N_ITER)
    assert src.text(0).startswith("update 1 of 3 (frame 8): ") and src.text(src.num_events).startswith(
        f"update 2 of 3 (frame 9): **iteration {src.num_events}/{src.num_events}**")
    pts = new_points(tiny_seg)
    for n in range(N_ITER[0] + 1):  # update 1's iterations: the scene before it has no added instance
        assert src.added(n) is None
    p, inst, col = src.added(N_ITER[0] + 1)  # update 2 optimises the added instance's pose
    assert np.all(inst == k) and len(p) == len(pts) and col.shape == (len(pts), 3)
    end, _, _ = src.added(src.num_events)
    np.testing.assert_allclose(end - pts, [[SHIFT_K, 0, 0]] * len(pts), atol=1e-5)
    steps = [src.added(n)[0][:, 0].mean() for n in range(N_ITER[0] + 1, src.num_events + 1)]
    assert np.all(np.diff(steps) > 0)  # it moves step by step
    # the run's displaced instance keeps its update-1 motion during update 2
    was0 = np.flatnonzero(tiny_seg.instance == 0)
    np.testing.assert_allclose(src.points(src.num_events, was0) - tiny_seg.points[was0], [[SHIFT_0, 0, 0]] * len(was0),
                               atol=1e-5)


def test_a_grasp_is_planned_on_an_added_instance(chain, tiny_seg):
    from clutt3r_core.registry import create_backend
    from clutt3r_viewer.scene_step import scene_grasp_request

    d, k = chain
    pts = new_points(tiny_seg)
    req = scene_grasp_request(d, 2, k)
    np.testing.assert_allclose(req.points[req.target] - pts, [[SHIFT_K, 0, 0]] * len(pts), atol=1e-5)
    assert req.instance == k and req.views == ()
    assert len(req.points) == int((tiny_seg.instance != 2).sum()) + len(pts)  # the removed instance is left out
    np.testing.assert_allclose(np.linalg.norm(req.normals, axis=1), 1.0, atol=1e-4)
    # the cube's face normals point out of it (towards the camera; here: no camera, +z for all faces but the bottom)
    tp = req.points[req.target]
    c = tp.mean(axis=0)
    top = (tp[:, 2] > c[2] + 0.014) & np.all(np.abs(tp[:, :2] - c[:2]) < 0.01, axis=1)  # the top face, edges apart
    assert top.sum() >= 49 and np.all(req.normals[req.target][top, 2] > 0.99)
    gs = create_backend("grasp_planner").plan(req)
    assert len(gs) > 0 and np.all(gs.instance == k)
    centres = gs.poses[:, :3, 3]
    assert np.all(np.abs(centres - c).max(axis=1) < 0.03)  # on the cube
    with pytest.raises(SceneError, match="not in the scene"):
        scene_grasp_request(d, 1, 2)  # removed by update 1


def test_every_colour_layer_colours_the_added_instances(chain):
    from clutt3r_viewer.data import GREY, PALETTE
    from clutt3r_viewer.layers import HIGHLIGHT, LayerInput, layer_added_colors, layer_named

    d, k = chain
    inst = np.array([k, k], np.int32)
    rgb = np.array([NEW_RGB, NEW_RGB], np.uint8)
    inp = LayerInput(d, np.arange(3), d.seg.instance, d.seg.scores)
    n = d.seg.num_instances
    scores = np.concatenate([np.linspace(0, 1, n), [0.5]]).astype(np.float32)
    st = SimpleNamespace(query_scores=scores, query_best=k, update=0, update_after=True)
    got = {name: layer_added_colors(layer_named(name), inp, st, inst, rgb)
           for name in ("instance", "rgb", "confidence", "query", "update")}
    assert np.all(got["instance"] == PALETTE[k % len(PALETTE)]) and np.all(got["update"] == got["instance"])
    assert np.all(got["rgb"] == NEW_RGB) and np.all(got["confidence"] == GREY) and np.all(got["query"] == HIGHLIGHT)
    st.query_best = 0
    mid = layer_added_colors(layer_named("query"), inp, st, inst, rgb)
    assert not np.all(mid == HIGHLIGHT) and not np.all(mid == GREY)  # on the ramp, by its score
    assert layer_named("query").available(inp, st)  # scores for the run's ids and the added one


def test_a_language_query_after_an_update_ranks_the_scene_then(tiny_run_dir, tiny_seg, tmp_path, monkeypatch):
    """The language backend describes the run's masks only: after update 1 the removed instance is
    not ranked (and cannot be the answer), the added one is listed as not ranked."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_viewer.loading import load_viewer_data

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run)
    d = load_viewer_data(run)  # with the scene's images: the backend describes their masks
    panel, s, state = fake_query_panel(d, monkeypatch)
    for text in ("red", "green", "blue", "yellow"):
        panel.run_query(s, f"the {text} thing")
        sc = state.query_scores
        assert sc is not None and len(sc) == k + 1 and np.isnan(sc[2]) and np.isnan(sc[k])
        assert state.query_best not in (2, k) and state.query_best == int(np.nanargmax(sc))
        assert f"not ranked: I{k}" in panel.result.content and "removed, not ranked: I2" in panel.result.content


def test_the_edit_tab_shows_the_run_before_it_picks():
    """Edits apply to the run's labels at the run's positions: a pick aimed at an updated scene
    switches the tab to the run (and says so) instead of selecting what lies there in the run."""
    from clutt3r_viewer.panels.edit import EditPanel

    calls = []
    s = SimpleNamespace(scene_step=lambda: 1, set_scene=lambda u, update_colours: calls.append(("scene", u)),
                        notify=lambda title, body: calls.append(("notify", body)))
    p = EditPanel.__new__(EditPanel)
    p.click_selects = SimpleNamespace(value=True)
    assert p.on_click(s, (0, 0, 1), (0, 0, -1)) == -1 and p.on_rect(s, (0, 0), (1, 1)) == 0
    assert [c[0] for c in calls] == ["scene", "notify"] * 2 and calls[0] == ("scene", -1)
    assert "showing the run" in calls[1][1]


def test_the_rerun_export_logs_the_scene_after_each_update(chain, tiny_seg):
    import rerun as rr

    from clutt3r_viewer.data import PALETTE
    from clutt3r_viewer.panels.update_sources import export_updates_rerun

    d, k = chain
    log, t = [], [0]

    class Rec:
        def set_time(self, name, sequence):
            if name == "update":
                t[0] = sequence

        def log(self, path, obj):
            log.append((t[0], path, obj))

    export_updates_rerun(Rec(), d, max_points=len(tiny_seg.points))
    scenes = {u: o for u, p, o in log if p == "world/updates/scene"}
    assert sorted(scenes) == [1, 2, 3]
    pts = new_points(tiny_seg)
    n_run = int((tiny_seg.instance != 2).sum())
    for u, extra, shift in ((1, len(pts), 0.0), (2, len(pts), SHIFT_K), (3, 0, None)):
        o = scenes[u]
        assert isinstance(o, rr.Points3D)
        xyz = np.asarray(o.positions.as_arrow_array().to_pylist(), np.float64)
        cols = np.asarray(o.colors.as_arrow_array().to_pylist(), np.uint64)
        assert len(xyz) == n_run + extra  # the removed instances left out (I2 from update 1, K from update 3)
        if extra:  # the added cube, after the run's points, in its instance colour, moved by update 2
            np.testing.assert_allclose(xyz[-extra:] - pts, [[shift, 0, 0]] * extra, atol=1e-5)
            r, g, b = (int(c) for c in PALETTE[k % len(PALETTE)])
            assert np.all(cols[-extra:] == (r << 24) | (g << 16) | (b << 8) | 255)


def test_only_a_few_scenes_are_cached(chain, tiny_seg):
    from clutt3r_viewer.scene_step import _CACHED_SCENES, shown_scene

    d, _ = chain
    for n in range(100, 100 + 2 * _CACHED_SCENES):  # one level of detail each
        shown_scene(d, 1 + n % 3, np.arange(n))
    cached = [k for k in d._cache if isinstance(k, tuple) and k[0] == "shown"]
    last = 99 + 2 * _CACHED_SCENES
    assert len(cached) == _CACHED_SCENES and ("shown", 1 + last % 3, last) in cached


def test_the_language_backend_describes_an_added_instance_from_its_mask(tiny_run_dir, tiny_seg, tiny_scene, tmp_path,
                                                                       monkeypatch):
    """An added instance whose mask is in the scene folder (its post view) is described by the
    backend like a run instance with one mask: the reddest mask of a view, added, scores for "red"
    within 0.1 of the run instance that mask belongs to (the fake backend grounds by red/green/blue
    shares), far above its own "green" and "blue" scores."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_core.language.colors import COLOR_WORDS, color_shares
    from clutt3r_viewer.loading import load_viewer_data

    v = tiny_scene.initial_views[0]
    red = color_shares(v.rgb, v.masks.stack())[:, COLOR_WORDS.index("red")]
    mask = int(v.masks.ids[int(np.argmax(red))])
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run, frame=int(v.frame), mask=mask)
    d = load_viewer_data(run)
    assert d.updates[0].result.added[0].mask_id == mask and d.updates[0].result.new_masks[0].instance == k
    panel, s, state = fake_query_panel(d, monkeypatch)
    nodes = d.trace.nodes
    owner = int(d.node_instance[np.flatnonzero((nodes.frame == v.frame) & (nodes.mask_id == mask))[0]])
    got = {}
    for text in ("red", "green", "blue"):
        panel.run_query(s, f"the {text} thing")
        got[text] = state.query_scores.copy()
        assert np.isfinite(got[text][k]) and np.isnan(got[text][2])  # described; the removed one is not ranked
        assert f"not ranked: I{k}" not in panel.result.content
    # described like the run instance whose mask it is (the same object seen in one view, not four)
    assert owner >= 0 and abs(got["red"][k] - got["red"][owner]) < 0.1
    assert got["red"][k] > max(got["green"][k], got["blue"][k]) + 1.0  # its mask is the view's reddest
