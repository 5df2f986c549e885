"""Colour layers, event sources and the default camera: no browser needed."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_viewer.camera import bounding_sphere, default_camera, object_points
from clutt3r_viewer.data import label_colors
from clutt3r_viewer.events import EVENT_SOURCES, EventSource, GroupingEvents, PoseIterations, event_sources
from clutt3r_viewer.layers import COLOR_LAYERS, LayerInput, available_layers, layer_named, register_color_layer
from clutt3r_viewer.state import SessionState


def _inp(d, n=None, replay=True):
    idx = np.arange(len(d.seg.points)) if n is None else np.sort(np.random.default_rng(0).choice(len(d.seg.points), n, False))
    return LayerInput(data=d, idx=idx, instance=d.seg.instance, scores=d.seg.scores,
                      replay=GroupingEvents(d) if replay else None)


def test_every_available_layer_colours_the_displayed_points(tiny_data):
    inp = _inp(tiny_data, n=500)
    state = SessionState(event=3, query_scores=np.linspace(0, 1, tiny_data.seg.num_instances).astype(np.float32),
                         query_best=0)
    names = [layer.name for layer in available_layers(inp, state)]
    assert names[:4] == ["instance", "rgb", "confidence", "replay"] and "query" in names
    assert "update" not in names  # the run has no post-interaction frames
    for layer in available_layers(inp, state):
        c = layer.colors(inp, state)
        assert c.shape == (500, 3) and c.dtype == np.uint8, layer.name
    assert np.array_equal(layer_named("instance").colors(inp, state), label_colors(tiny_data.seg.instance[inp.idx]))
    q = layer_named("query").colors(inp, state)
    assert (q[tiny_data.seg.instance[inp.idx] == 0] == [255, 215, 0]).all()  # the best instance highlighted


def test_query_and_replay_layers_are_offered_only_with_their_input(tiny_data):
    names = [layer.name for layer in available_layers(_inp(tiny_data, replay=False), SessionState())]
    assert "query" not in names and "replay" not in names


def test_a_registered_layer_is_appended_and_offered(tiny_data):
    class Height:
        name = "height"

        def available(self, inp, state):
            return True

        def colors(self, inp, state):
            z = inp.data.seg.points[inp.idx, 2]
            return np.repeat(((z - z.min()) / max(np.ptp(z), 1e-9) * 255).astype(np.uint8)[:, None], 3, axis=1)

    register_color_layer(Height())
    try:
        assert [layer.name for layer in available_layers(_inp(tiny_data, 100), SessionState())][-1] == "height"
        register_color_layer(Height())  # same name: replaced, not duplicated
        assert sum(layer.name == "height" for layer in COLOR_LAYERS) == 1
    finally:
        COLOR_LAYERS[:] = [layer for layer in COLOR_LAYERS if layer.name != "height"]


def test_grouping_events_follow_the_trace(tiny_data):
    src = GroupingEvents(tiny_data)
    assert isinstance(src, EventSource) and [s.name for s in event_sources(tiny_data)] == ["grouping"]
    n = src.num_events
    assert n == len(tiny_data.trace.grouping.events) > 0
    idx = np.arange(len(tiny_data.seg.points))
    end = src.colors(n, idx)
    assert np.array_equal(end, label_colors(tiny_data.replay_sv_group(n)[tiny_data.seg.sv_labels]))
    assert src.points(n, idx) is None
    assert f"{n}/{n}" in src.text(n) and "start" in src.text(0)
    # groups merged between the start and the end, and the colours show it
    assert tiny_data.replay_num_groups(0) > tiny_data.replay_num_groups(n)
    assert (src.colors(0, idx) != end).any(axis=1).mean() > 0.01


def test_a_registered_event_source_is_listed_after_grouping(tiny_data):
    def none_here(data):
        return None

    EVENT_SOURCES.append(none_here)
    try:
        assert [s.name for s in event_sources(tiny_data)] == ["grouping"]  # a factory may decline
    finally:
        EVENT_SOURCES.remove(none_here)


@settings(max_examples=40, deadline=None)
@given(t=st.integers(1, 5), shift=st.lists(st.floats(-0.2, 0.2), min_size=3, max_size=3),
       yaw=st.floats(-np.pi, np.pi), seed=st.integers(0, 1000))
def test_pose_iterations_move_each_object_rigidly(t, shift, yaw, seed):
    rng = np.random.default_rng(seed)
    n, k = 60, 3
    pts = rng.uniform(-0.3, 0.3, (n, 3)).astype(np.float32)
    inst = rng.integers(-1, k, n)
    poses = np.tile(np.eye(4), (t + 1, k, 1, 1))
    c, s = np.cos(yaw), np.sin(yaw)
    poses[t, 1, :3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    poses[t, 1, :3, 3] = shift
    src = PoseIterations(instance=inst, poses=poses, residual=rng.uniform(0, 1, (t + 1, k)), points0=pts)
    assert isinstance(src, EventSource) and src.num_events == t
    idx = np.arange(n)
    assert np.allclose(src.points(0, idx), pts, atol=1e-6)  # iteration 0: the run as it is
    moved = src.points(t, idx)
    assert np.allclose(moved[inst != 1], pts[inst != 1], atol=1e-6)  # others (and static points) stay
    a = pts[inst == 1].astype(np.float64)
    b = moved[inst == 1].astype(np.float64)
    if len(a) >= 2:  # rigid: pairwise distances kept
        assert np.allclose(np.linalg.norm(a[:, None] - a[None], axis=-1), np.linalg.norm(b[:, None] - b[None], axis=-1),
                           atol=1e-5)
    col = src.colors(t, idx)
    assert col.shape == (n, 3) and col.dtype == np.uint8
    assert "iteration" in src.text(t)


def test_pose_iterations_reject_mismatched_shapes():
    with pytest.raises(ValueError, match="poses"):
        PoseIterations(instance=np.zeros(4, int), poses=np.zeros((2, 3, 4, 4)), residual=np.zeros((2, 2)),
                       points0=np.zeros((4, 3), np.float32))


def test_pose_replay_draws_static_points_in_their_own_dimmed_colour():
    # the tour's pose step: grey static points on a grey background hid the scene around the pushed object
    pts = np.zeros((4, 3), np.float32)
    rgb = np.array([[200, 100, 50], [10, 20, 30], [255, 255, 255], [0, 0, 0]], np.uint8)
    inst = np.array([-1, 0, -1, 0])
    src = PoseIterations(instance=inst, poses=np.tile(np.eye(4), (2, 1, 1, 1)), residual=np.ones((2, 1)),
                         points0=pts, context_rgb=rgb)
    col = src.colors(1, np.arange(4)).astype(int)
    assert np.all(np.abs(col[[0, 2]] - rgb[[0, 2]] * 0.55) <= 1)
    plain = PoseIterations(instance=inst, poses=src.poses, residual=src.residual, points0=pts)
    assert np.array_equal(col[[1, 3]], plain.colors(1, np.arange(4))[[1, 3]])  # moving points: the loss ramp
    with pytest.raises(ValueError):
        PoseIterations(instance=inst, poses=src.poses, residual=src.residual, points0=pts, context_rgb=rgb[:3])


def test_default_camera_frames_the_objects_not_the_support(tiny_data):
    d = tiny_data
    cam = default_camera(d)
    c, r = bounding_sphere(object_points(d))
    assert np.allclose(cam.look_at, c)
    dist = float(np.linalg.norm(cam.position - cam.look_at))
    # the objects' sphere fills the view height up to the margin: r / dist = sin(fov/2) / MARGIN
    from clutt3r_viewer.camera import MARGIN

    assert np.isclose(r / dist, np.sin(cam.fov / 2) / MARGIN, rtol=1e-6)
    # support points are left out: the sphere is smaller than the one of the whole cloud
    _, r_all = bounding_sphere(d.seg.points.astype(np.float64))
    assert r < r_all
    # every object point (but the 1 % outliers) projects inside the vertical field of view
    f = (cam.look_at - cam.position) / dist
    rel = object_points(d) - cam.position
    ang = np.arccos(np.clip((rel @ f) / np.linalg.norm(rel, axis=1), -1, 1))
    assert np.mean(ang <= cam.fov / 2) >= 0.99
