"""Object points at the table contact left unlabelled (segmentation/refine.py ``table_contact``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.refine import RefineConfig, table_contact

# a tilted plane, unit normal towards the cameras: n . x + d = 0
N = np.array([0.0, 0.6, 0.8])
PLANE = np.r_[N, -0.1]


def at_heights(h: np.ndarray, seed: int = 0) -> np.ndarray:
    """Points at signed heights h (metres) above PLANE, spread over it."""
    rng = np.random.default_rng(seed)
    t1, t2 = np.array([1.0, 0.0, 0.0]), np.cross(N, [1.0, 0.0, 0.0])
    base = -PLANE[3] * N + rng.uniform(-0.3, 0.3, (len(h), 1)) * t1 + rng.uniform(-0.3, 0.3, (len(h), 1)) * t2
    return base + np.asarray(h)[:, None] * N


def test_only_labelled_points_below_the_height_are_marked():
    h = np.array([-0.004, 0.0, 0.0015, 0.0025, 0.01, 0.0005, 0.05])
    inst = np.array([0, 1, 2, 0, 1, -1, 2])
    m = table_contact(at_heights(h), inst, PLANE, 0.002)
    assert m.tolist() == [True, True, True, False, False, False, False]  # the unlabelled 0.5 mm point stays as it is
    # off, or no plane: nothing
    assert not table_contact(at_heights(h), inst, PLANE, 0.0).any()
    assert not table_contact(at_heights(h), inst, None, 0.002).any()
    assert table_contact(np.zeros((0, 3)), np.zeros(0, int), PLANE, 0.002).shape == (0,)


def test_config_checks_the_height_and_presets():
    from clutt3r_core.config import PRESETS

    with pytest.raises(SceneError, match="contact_height"):
        RefineConfig(contact_height=-0.001)
    with pytest.raises(SceneError, match="contact_height"):
        RefineConfig(contact_height=0.2)  # metres, not millimetres
    # off by default (it costs grasps and a real update, RefineConfig says why) and in the paper preset
    assert PRESETS["default"].refine.contact_height == 0.0 and PRESETS["paper"].refine.contact_height == 0.0


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-0.02, 0.05), min_size=1, max_size=40), st.floats(0.0, 0.01), st.floats(0.0, 0.01),
       st.integers(0, 1000))
def test_marked_points_grow_with_the_height_and_are_labelled(hs, a, b, seed):
    h = np.array(hs)
    inst = np.random.default_rng(seed).integers(-1, 3, len(h))
    p = at_heights(h, seed)
    lo, hi = table_contact(p, inst, PLANE, min(a, b)), table_contact(p, inst, PLANE, max(a, b))
    assert not (lo & ~hi).any()  # monotone in the height
    assert (inst[hi] >= 0).all()  # never touches what is already unlabelled
    # every marked point lies below the height (1e-9: the points' own rounding)
    assert (h[hi] < max(a, b) + 1e-9).all()


def test_pipeline_unlabels_only_the_contact():
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from clutt3r_core.pointcloud import fuse_views
    from clutt3r_core.supervoxels import build_supervoxels
    from clutt3r_core.synth.generator import SynthConfig, generate_scene

    # RealSense-like depth: on clean depth no labelled point reaches within 2 mm of the table
    # (the support rule takes the lowest 10 mm; measured on tests.core.test_pipeline.small_scene)
    scene = generate_scene(SynthConfig(seed=0, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    on = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.002}))
    off = segment(scene)
    assert np.array_equal(on.points, off.points) and np.array_equal(on.scores, off.scores)
    changed = on.instance != off.instance
    assert changed.any()  # this scene's objects rest on the table: some contact points were labelled (measured)
    assert (on.instance[changed] == -1).all() and (off.instance[changed] >= 0).all()
    # exactly the labelled points within 2 mm of the pipeline's support plane
    cfg = SegmentConfig()
    plane = build_supervoxels(fuse_views(scene.initial_views, cfg.pointcloud), cfg.supervoxels).plane
    assert np.array_equal(changed, table_contact(off.points, off.instance, plane, 0.002))


def test_clean_depth_is_left_alone():
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from tests.core.test_pipeline import small_scene

    # clean depth: the fusion keeps the plain voxels (no surface estimate), so the rule does not run,
    # even forced high enough to reach the objects' lowest points (2.3 mm above the plane, measured)
    scene = small_scene(0)
    hi = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.03}))
    assert hi.trace.surface.method == "voxel-mean"
    off = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.0}))
    assert np.array_equal(hi.instance, off.instance)
