"""The gripper boxes are the numbers of the convention (docs/conventions.md, "Gripper")."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.grasping.gripper import FRANKA, Box, box_grid


def test_boxes_match_the_convention():
    w = 0.05
    b = FRANKA.boxes(w)
    np.testing.assert_allclose(b["closing"].lo, [-w / 2, -0.01, -0.02])
    np.testing.assert_allclose(b["closing"].hi, [w / 2, 0.01, 0.02])
    np.testing.assert_allclose(b["finger_right"].lo, [w / 2, -0.01, -0.045])
    np.testing.assert_allclose(b["finger_right"].hi, [w / 2 + 0.01, 0.01, 0.02])
    np.testing.assert_allclose(b["finger_left"].lo, [-w / 2 - 0.01, -0.01, -0.045])
    np.testing.assert_allclose(b["finger_left"].hi, [-w / 2, 0.01, 0.02])
    np.testing.assert_allclose(b["palm"].lo, [-0.105, -0.03, -0.11])
    np.testing.assert_allclose(b["palm"].hi, [0.105, 0.03, -0.045])
    assert FRANKA.max_width == 0.08


@pytest.mark.parametrize("w", [0.0, -0.01, 0.0801])
def test_width_out_of_range_is_refused(w):
    with pytest.raises(SceneError, match="width"):
        FRANKA.boxes(w)


def test_the_mesh_file_is_drawn_from_the_same_numbers():
    from clutt3r_viewer.assets import gripper_parts

    gripper_parts.cache_clear()
    parts = gripper_parts()
    if parts is None:
        pytest.skip("static/ not beside the package (wheel install)")
    boxes = FRANKA.boxes(FRANKA.max_width)
    for name in ("palm", "finger_left", "finger_right"):
        v = parts[name][0]
        np.testing.assert_allclose(v.min(0), boxes[name].lo, atol=1e-6)
        np.testing.assert_allclose(v.max(0), boxes[name].hi, atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(st.tuples(*[st.floats(0.002, 0.1)] * 3), st.floats(0.003, 0.02),
       st.tuples(*[st.floats(-1, 1)] * 3))
def test_box_grid_covers_the_box(half, spacing, frac):
    """Every point of the box lies within the cover radius of a sample (the planner's proof of freedom)."""
    box = Box((0.01, -0.02, 0.03), half)
    s, r = box_grid(box, spacing)
    assert box.contains(s).all()
    p = np.asarray(box.centre) + np.asarray(frac) * np.asarray(half)
    assert np.linalg.norm(s - p, axis=1).min() <= r + 1e-12
