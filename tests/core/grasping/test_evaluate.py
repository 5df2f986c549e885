"""The GraspNet-style evaluator on hand-made cases (true meshes, table z = 0)."""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.grasping.evaluate import EvalConfig, GraspEvaluator, SceneGeometry, boxes_overlap
from tests.core.grasping._box_scene import box_mesh

BOX = ((-0.02, -0.03, 0.0), (0.02, 0.03, 0.07))  # 4 x 6 x 7 cm on the table
FAR = ((0.15, -0.03, 0.0), (0.19, 0.03, 0.07))


def _pose(x, z, centre) -> np.ndarray:
    x, z = np.asarray(x, float), np.asarray(z, float)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
    T[:3, 3] = centre
    return T


@pytest.fixture(scope="module")
def ev() -> GraspEvaluator:
    return GraspEvaluator(SceneGeometry((box_mesh(*BOX), box_mesh(*FAR)), (), 0.0), EvalConfig())


def test_box_grasped_across_its_faces_succeeds(ev):
    T = _pose((1, 0, 0), (0, 0, -1), (0.0, 0.0, 0.05))  # from above, closing across the 4 cm
    e = ev.evaluate(T[None], [0.06], 0)
    assert not e.collision[0] and e.holds[0]
    assert e.min_mu[0] < 0.05 and e.success(0.2)[0]
    np.testing.assert_allclose(np.abs(e.contacts[0, :, 0]), 0.02, atol=1e-3)  # on the two x faces
    assert e.contacts[0, 0, 0] < 0  # x < 0 finger first


def test_too_narrow_opening_collides_with_the_target(ev):
    T = _pose((1, 0, 0), (0, 0, -1), (0.0, 0.0, 0.05))
    e = ev.evaluate(T[None], [0.03], 0)
    assert e.collision[0] and not e.success(1.2)[0]


def test_gripper_inside_the_table_fails(ev):
    T = _pose((1, 0, 0), (0, 0, -1), (0.0, 0.0, 0.01))  # fingertips 1 cm under the table top
    e = ev.evaluate(T[None], [0.06], 0)
    assert e.collision[0] and not e.success(1.2)[0]


def test_grasp_on_the_wrong_object_fails_the_holds_target_rule(ev):
    T = _pose((1, 0, 0), (0, 0, -1), (0.17, 0.0, 0.05))  # a fine grasp of object 1 ...
    assert ev.evaluate(T[None], [0.06], 1).success(0.2)[0]
    e = ev.evaluate(T[None], [0.06], 0)  # ... judged as a grasp of object 0
    assert not e.holds[0] and not e.success(1.2)[0]


def test_closing_region_with_a_second_object_fails():
    a = ((-0.02, -0.03, 0.0), (0.0, 0.03, 0.07))
    b = ((0.005, -0.03, 0.0), (0.02, 0.03, 0.07))  # 5 mm gap: both between the fingers
    ev2 = GraspEvaluator(SceneGeometry((box_mesh(*a), box_mesh(*b)), (), 0.0))
    T = _pose((1, 0, 0), (0, 0, -1), (0.0, 0.0, 0.05))
    e = ev2.evaluate(T[None], [0.06], 0)
    assert not e.collision[0] and not e.holds[0]


def test_gripper_wholly_inside_a_mesh_collides():
    ev3 = GraspEvaluator(SceneGeometry((box_mesh((-0.2, -0.2, 0.0), (0.2, 0.2, 0.4)),), (), None))
    T = _pose((1, 0, 0), (0, 0, -1), (0.0, 0.0, 0.2))
    assert ev3.evaluate(T[None], [0.05], 0).collision[0]


def test_support_box_collision():
    T = _pose((1, 0, 0), (0, 0, -1), (0.0, 0.0, 0.05))  # palm spans world z 0.095 .. 0.16, |x| <= 0.105
    low = (np.array([0.06, 0.0, 0.03]), np.array([0.006, 0.2, 0.03]))  # a tray wall up to z = 0.06
    high = (np.array([0.06, 0.0, 0.06]), np.array([0.006, 0.2, 0.06]))  # ... up to z = 0.12
    for wall, hit in ((low, False), (high, True)):
        ev4 = GraspEvaluator(SceneGeometry((box_mesh(*BOX),), (wall,), 0.0))
        assert ev4.evaluate(T[None], [0.06], 0).collision[0] == hit


def test_boxes_overlap_separating_axes():
    I = np.eye(3)
    h = np.array([0.01, 0.01, 0.01])
    assert boxes_overlap(np.zeros(3), I, h, np.array([0.015, 0, 0]), I, h)
    assert not boxes_overlap(np.zeros(3), I, h, np.array([0.025, 0, 0]), I, h)
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    # a 45 deg box reaches sqrt(2) * 0.01 along x
    assert boxes_overlap(np.zeros(3), I, h, np.array([0.0235, 0, 0]), R, h)
    assert not boxes_overlap(np.zeros(3), I, h, np.array([0.0245, 0, 0]), R, h)
