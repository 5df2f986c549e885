"""static/ assets: the gripper mesh follows the grasp's pose and width; the logo is embedded."""

from __future__ import annotations

import numpy as np

from clutt3r_viewer.assets import gripper_mesh, gripper_parts, logo_data_uri
from tests.viewer.conftest import free_port


def test_gripper_parts_are_the_three_named_boxes():
    parts = gripper_parts()
    assert parts is not None and set(parts) == {"palm", "finger_left", "finger_right"}
    for v, f in parts.values():
        assert v.shape == (8, 3) and f.shape == (12, 3) and f.min() >= 0 and f.max() < 8


def test_gripper_mesh_opens_to_the_width_and_follows_the_pose():
    width = 0.05
    V, F = gripper_mesh(np.eye(4), width)
    parts = gripper_parts()
    n_left = len(parts["palm"][0])
    left = V[n_left : n_left + 8]
    right = V[n_left + 8 : n_left + 16]
    # inner finger faces are exactly `width` apart around the grasp centre, fingertips at the
    # convention's z (docs/conventions.md, "Gripper"), the palm keeps its size
    from clutt3r_core.grasping.gripper import FRANKA

    assert np.isclose(right[:, 0].min() - left[:, 0].max(), width, atol=1e-6)
    assert np.isclose(left[:, 0].max(), -width / 2, atol=1e-6)
    assert np.isclose(V[:, 2].max(), FRANKA.finger_z[1], atol=1e-6)
    assert np.isclose(V[:len(parts["palm"][0]), 0].max(), FRANKA.palm_half_x, atol=1e-6)
    # a pose moves every vertex rigidly
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.1, 0.2, 0.3]
    V2, F2 = gripper_mesh(T, width)
    np.testing.assert_allclose(V2, V @ T[:3, :3].T + T[:3, 3], atol=1e-6)
    np.testing.assert_array_equal(F2, F)


def test_logo_is_an_svg_data_uri_and_the_server_starts_with_it():
    uri = logo_data_uri()
    assert uri is not None and uri.startswith("data:image/svg+xml;base64,")
    from clutt3r_viewer.app import ViewerApp

    app = ViewerApp(data=None, port=free_port())
    try:
        assert app.port > 0
    finally:
        app.stop()
