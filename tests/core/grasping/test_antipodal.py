"""The antipodal planner on exactly rendered box scenes: invariants, true-mesh success, empty results."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutt3r_core.grasping import GraspRequest
from clutt3r_core.grasping.antipodal import AntipodalConfig, AntipodalPlanner, plan_antipodal, unseen_occupied
from clutt3r_core.grasping.evaluate import GraspEvaluator
from clutt3r_core.grasping.gripper import FRANKA
from clutt3r_core.registry import create_backend
from tests.core.grasping._box_scene import box_request, box_scene


def check_invariants(req: GraspRequest, gs) -> None:
    """Rigid right-handed frames, widths in range, ranked, and the fused cloud respected exactly:
    no point in a finger, target points and nothing else in the closing region."""
    assert len(gs) > 0
    R = gs.poses[:, :3, :3]
    np.testing.assert_allclose(np.einsum("gji,gjk->gik", R, R), np.broadcast_to(np.eye(3), R.shape), atol=1e-6)
    assert np.all(np.linalg.det(R) > 0.999)
    assert np.all((gs.widths > 0) & (gs.widths <= FRANKA.max_width + 1e-6))
    assert np.all(np.diff(gs.scores) <= 1e-7) and np.all((gs.scores >= 0) & (gs.scores <= 1))
    for T, w in zip(gs.poses, gs.widths):
        loc = (req.points - T[:3, 3]) @ T[:3, :3]
        b = FRANKA.boxes(float(w))
        assert not b["finger_left"].contains(loc).any() and not b["finger_right"].contains(loc).any()
        assert not b["palm"].contains(loc).any()
        inc = b["closing"].contains(loc)
        assert (inc & req.target).sum() >= 3 and not (inc & ~req.target).any()


def test_box_grasps_respect_the_cloud_and_succeed_on_the_true_mesh():
    req = box_request()
    gs, stats = plan_antipodal(req)
    check_invariants(req, gs)
    assert gs.message == "" and (gs.instance == 0).all() and gs.contacts.shape == (len(gs), 2, 3)
    ev = GraspEvaluator(box_scene()[3])
    e = ev.evaluate(gs.poses[:5], gs.widths[:5], 0)
    # a box is the easy case: the top 5 are collision-free, hold only the box, force closure at mu 0.2
    assert e.success(0.2).all(), (e.collision, e.holds, e.min_mu)
    assert gs.poses[0][2, 2] < -0.7  # the best approaches from above (the default preference)
    assert stats.returned == len(gs) and stats.candidates >= stats.after_fingers >= stats.after_unseen


def test_preferred_approach_is_followed():
    gs, _ = plan_antipodal(box_request(), AntipodalConfig(preferred_approach=(-1.0, 0.0, 0.0), min_approach_dot=-1))
    assert len(gs) and gs.poses[0][0, 2] < -0.5  # from +x towards -x


def test_registry_builds_the_planner():
    p = create_backend("grasp_planner")
    assert isinstance(p, AntipodalPlanner) and p.name == "antipodal"
    assert len(p.plan(box_request())) > 0


def test_too_big_and_too_small_targets_give_an_empty_set_with_a_reason():
    wide = (((-0.07, -0.07, 0.0), (0.07, 0.07, 0.05)),)  # 14 cm square: no opening fits
    gs, _ = plan_antipodal(box_request(boxes=wide))
    assert len(gs) == 0 and "fits the hand" in gs.message
    req = box_request()
    tiny = np.zeros_like(req.target)
    tiny[np.flatnonzero(req.target)[:2]] = True
    gs, _ = plan_antipodal(GraspRequest(req.points, req.normals, tiny, 0, req.views))
    assert len(gs) == 0 and "2 points" in gs.message
    none = GraspRequest(req.points, req.normals, np.zeros_like(req.target), 0, req.views)
    assert len(AntipodalPlanner().plan(none)) == 0


def test_unseen_space_is_what_every_view_sees_behind_a_surface():
    _, views, _, _ = box_scene()
    p = np.array([[0.0, 0.0, 0.035],  # inside the box
                  [0.1, 0.1, -0.02],  # under the table top
                  [0.0, 0.0, 0.2],  # in the air above the box
                  [5.0, 5.0, 0.1]])  # outside every image
    np.testing.assert_array_equal(unseen_occupied(p, views, 0.006), [True, True, False, False])


def test_without_the_table_in_the_cloud_the_views_still_keep_fingers_out_of_it():
    """Drop the table's points: only the unseen-space check knows the table is solid."""
    req = box_request()
    keep = req.points[:, 2] > 0.004
    bare = GraspRequest(req.points[keep], req.normals[keep], req.target[keep], 0, req.views)
    cfg = AntipodalConfig(preferred_approach=(1.0, 0.0, 0.0), min_approach_dot=-1.0)  # invite low side grasps
    for with_views in (True, False):
        r = bare if with_views else GraspRequest(bare.points, bare.normals, bare.target, 0, ())
        gs, _ = plan_antipodal(r, cfg)
        lowest = min(_lowest_z(T, float(w)) for T, w in zip(gs.poses, gs.widths))
        if with_views:
            assert lowest > -0.01
        else:
            assert "unseen space was not checked" in gs.message
            assert lowest < -0.01  # the cloud alone lets grippers sink into the table


def _lowest_z(T: np.ndarray, w: float) -> float:
    z = []
    for name in ("finger_left", "finger_right", "palm"):
        b = FRANKA.boxes(w)[name]
        c = np.array([[sx, sy, sz] for sx in (0, 1) for sy in (0, 1) for sz in (0, 1)])
        corners = b.lo + c * (b.hi - b.lo)
        z.append((corners @ T[:3, :3].T + T[:3, 3])[:, 2].min())
    return float(min(z))


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.floats(0.015, 0.03), st.floats(0.015, 0.03), st.floats(0.025, 0.05), st.floats(-0.03, 0.03))
def test_invariants_on_random_boxes(hx, hy, h, cx):
    boxes = (((cx - hx, -hy, 0.0), (cx + hx, hy, h)),)
    req = box_request(boxes=boxes)
    gs, _ = plan_antipodal(req)
    check_invariants(req, gs)


def test_contacts_are_the_first_touch_points_inside_the_closing_region():
    req = box_request()
    gs, _ = plan_antipodal(req)
    tp = req.target_points
    for T, w, c in zip(gs.poses[:5], gs.widths[:5], gs.contacts[:5]):
        loc = (c - T[:3, 3]) @ T[:3, :3]
        assert FRANKA.boxes(float(w))["closing"].contains(loc).all()
        assert loc[0, 0] < 0 < loc[1, 0]  # x < 0 finger first
        inside = FRANKA.boxes(float(w))["closing"].contains((tp - T[:3, 3]) @ T[:3, :3])
        x_in = ((tp[inside] - T[:3, 3]) @ T[:3, :3])[:, 0]
        np.testing.assert_allclose(loc[:, 0], [x_in.min(), x_in.max()], atol=1e-5)
