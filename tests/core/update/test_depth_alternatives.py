"""The depth registration's next-best poses (``ChangeConfig.registration_alternatives``, session 6
second pass) and its per-instance preparation (``depth.prepare_model``). Tiny scenes: the boxes of
``_scenes.two_boxes_on_a_table``, box 0 pushed and turned."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st_

import clutt3r_core.update.depth_change as depth_change
from clutt3r_core.errors import SceneError
from clutt3r_core.update.depth import Registration, _same_pose, mask_points, prepare_model, register, start_rotations
from clutt3r_core.update.types import ChangeConfig, UpdateConfig
from clutt3r_core.update.update import update_scene

from ._scenes import camera, render_view
from .test_depth import CAM, FAST
from .test_depth_regions import _pushed


def _setup(yaw: float, seed: int = 0, n: int = 120):
    pts, cols, inst, st, c, T, moved = _pushed(yaw)
    v = render_view(moved, cols, inst, camera(**CAM), frame=8)
    m = v.masks.masks[list(v.masks.ids).index(1)]
    scene = mask_points(v.camera, v.depth, m, max_points=n, seed=seed)
    return st, v, scene, c, T


@settings(max_examples=8, deadline=None)
@given(st_.floats(-60.0, 60.0), st_.integers(0, 3))
def test_alternatives_leave_the_pick_alone_and_are_distinct_and_ranked(yaw, seed):
    st, v, scene, c, T = _setup(yaw, seed)
    model = st.points_of(0).astype(np.float64)
    kw = dict(starts=start_rotations(30.0), tol=0.01, seed=seed, keep_consistent=4)
    a = register(model, scene, v.camera, v.depth, **kw)
    b = register(model, scene, v.camera, v.depth, alternatives=3, **kw)
    assert a.alternatives == ()
    np.testing.assert_array_equal(a.T_world, b.T_world)
    assert (a.score, a.fitness, a.consistency) == (b.score, b.fitness, b.consistency)
    assert 1 <= len(b.alternatives) <= 3  # 12 kept starts: at least two distinct poses on a box
    poses = [b.T_world] + [r.T_world for r in b.alternatives]
    centre = model.mean(axis=0)
    for i in range(len(poses)):
        for j in range(i + 1, len(poses)):
            assert not _same_pose(poses[i], poses[j], centre)
    scores = [r.score for r in b.alternatives]
    assert scores == sorted(scores, reverse=True)  # no colour term: the rank is the score
    for r in b.alternatives:
        assert r.alternatives == () and r.path is not None and np.array_equal(r.path[-1], r.T_world)


def test_a_prepared_model_registers_as_its_points():
    # depth_change prepares each instance once for all its targets: the same bits as the points
    st, v, scene, c, T = _setup(20.0)
    model = st.points_of(0).astype(np.float64)
    prepared = prepare_model(model, st.colors[st.instance == 0])
    for target in (scene, scene[::2]):
        kw = dict(starts=start_rotations(30.0), tol=0.01, keep_consistent=4, alternatives=2)
        a = register(model, target, v.camera, v.depth, **kw)
        b = register(prepared, target, v.camera, v.depth, **kw)
        np.testing.assert_array_equal(a.T_world, b.T_world)
        np.testing.assert_array_equal(a.path, b.path)
        assert [r.score for r in a.alternatives] == [r.score for r in b.alternatives]
    # a subset above max_model_points is the seeded one, in the points' order
    small = prepare_model(model, None, max_model_points=50, seed=3)
    assert len(small.points) == 50 and small.colors is None
    assert np.all(np.isin(small.points.view("f8,f8,f8"), model.view("f8,f8,f8")))


def _shifted(reg: Registration, dx: float) -> Registration:
    """``reg`` moved ``dx`` metres along x, with its fitness and consistency (only the IoU fails)."""
    T = reg.T_world.copy()
    T[0, 3] += dx
    return replace(reg, T_world=T, path=None, path_cost=None, alternatives=())


def test_the_acceptance_takes_the_first_alternative_that_passes(monkeypatch):
    # the registration's pick fails the IoU test (a pose 6 cm off, with the true pose's fitness
    # and consistency) and its first alternative is the true pose: hard_1701's case. Without
    # alternatives the pushed box is removed; with them it is displaced by the alternative.
    st, v, scene, c, T = _setup(20.0)
    real = depth_change.register

    def fake(*a, alternatives=0, **k):
        r = real(*a, alternatives=0, **k)
        if r is None:
            return None
        wrong = _shifted(r, 0.06)
        return replace(wrong, alternatives=(r,)) if alternatives else wrong

    monkeypatch.setattr(depth_change, "register", fake)
    off = update_scene(st, v, UpdateConfig(change=replace(FAST.change, registration_alternatives=0), pose=FAST.pose))
    assert off.record(0).status == "removed"
    on = update_scene(st, v, UpdateConfig(change=replace(FAST.change, registration_alternatives=3), pose=FAST.pose))
    r0 = on.record(0)
    assert r0.status == "displaced" and on.record(1).status == "static"
    est = r0.T_world[:3, :3] @ c + r0.T_world[:3, 3]
    assert np.linalg.norm(est - (T[:3, :3] @ c + T[:3, 3])) < 0.005


def test_a_pick_that_passes_is_kept_whatever_the_alternatives(monkeypatch):
    st, v, scene, c, T = _setup(20.0)
    cfg = UpdateConfig(change=replace(FAST.change, registration_alternatives=3), pose=FAST.pose)
    ref = update_scene(st, v, cfg)
    real = depth_change.register

    def fake(*a, **k):  # a passing pick, then a wrong alternative first in line
        r = real(*a, **k)
        return None if r is None else replace(r, alternatives=(_shifted(r, 0.06),) + r.alternatives)

    monkeypatch.setattr(depth_change, "register", fake)
    got = update_scene(st, v, cfg)
    assert got.record(0).status == ref.record(0).status == "displaced"
    np.testing.assert_array_equal(got.record(0).T_world, ref.record(0).T_world)


def test_registration_alternatives_is_checked():
    with pytest.raises(SceneError, match="registration_alternatives"):
        ChangeConfig(registration_alternatives=-1)


def test_only_moved_instances_get_alternatives(monkeypatch):
    # a hidden (unsure) instance keeps the registration's pick: an alternative is a static
    # object's chance to be flagged (hard_902)
    st, v, scene, c, T = _setup(20.0)
    real, asked = depth_change.register, []

    def spy(model, pts, *a, alternatives=0, **k):
        asked.append(alternatives)
        return real(model, pts, *a, alternatives=alternatives, **k)

    monkeypatch.setattr(depth_change, "register", spy)
    m = v.masks.masks[list(v.masks.ids).index(1)]
    targets = [(0, scene, float(np.linalg.norm(np.ptp(scene, axis=0))), m)]
    cfg = UpdateConfig(change=replace(FAST.change, registration_alternatives=3, max_extent_ratio=10.0), pose=FAST.pose)
    depth_change._register_all(st, v, cfg, [0, 1], targets, start_rotations(30.0), None, lambda k: 0.4, {0})
    assert asked == [3, 0]
    asked.clear()
    depth_change._register_all(st, v, cfg, [0, 1], targets, start_rotations(30.0), None, lambda k: 0.4)
    assert asked == [3, 3]  # None: every instance (the region and mask-pair searches: moved ones only)
