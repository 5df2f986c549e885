"""Object points at the table contact left unlabelled (segmentation/refine.py ``contact_labels``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.refine import RefineConfig, contact_labels, support_levels

# a tilted plane, unit normal towards the cameras: n . x + d = 0
N = np.array([0.0, 0.6, 0.8])
PLANE = np.r_[N, -0.1]


def at_heights(h: np.ndarray, seed: int = 0) -> np.ndarray:
    """Points at signed heights h (metres) above PLANE, spread over it."""
    rng = np.random.default_rng(seed)
    t1, t2 = np.array([1.0, 0.0, 0.0]), np.cross(N, [1.0, 0.0, 0.0])
    base = -PLANE[3] * N + rng.uniform(-0.3, 0.3, (len(h), 1)) * t1 + rng.uniform(-0.3, 0.3, (len(h), 1)) * t2
    return base + np.asarray(h)[:, None] * N


def sideways(m: int) -> np.ndarray:
    """(m, 3) unit normals along the plane (no point faces up, so no support level is measured and
    every object's level is the plane itself: heights above it decide)."""
    return np.tile([1.0, 0.0, 0.0], (m, 1))


def cleared(p: np.ndarray, inst: np.ndarray, plane, height: float) -> np.ndarray:
    """``contact_labels``' cleared points of 3 objects on ``plane`` with normals along it."""
    r = contact_labels(p, sideways(len(p)), inst, 3, plane, RefineConfig(contact_height=height, contact_fill_high=0.0))
    assert not r.level.any() and np.array_equal(r.instance, np.where(r.cleared, -1, inst))
    return r.cleared


def test_only_labelled_points_below_the_height_are_marked():
    h = np.array([-0.004, 0.0, 0.0015, 0.0025, 0.01, 0.0005, 0.05])
    inst = np.array([0, 1, 2, 0, 1, -1, 2])
    m = cleared(at_heights(h), inst, PLANE, 0.002)
    assert m.tolist() == [True, True, True, False, False, False, False]  # the unlabelled 0.5 mm point stays as it is
    # off, or no plane: nothing
    assert not cleared(at_heights(h), inst, PLANE, 0.0).any()
    assert not cleared(at_heights(h), inst, None, 0.002).any()
    assert cleared(np.zeros((0, 3)), np.zeros(0, int), PLANE, 0.002).shape == (0,)


def test_config_checks_the_height_and_presets():
    from clutt3r_core.config import PRESETS

    with pytest.raises(SceneError, match="contact_height"):
        RefineConfig(contact_height=-0.001)
    with pytest.raises(SceneError, match="contact_height"):
        RefineConfig(contact_height=0.2)  # metres, not millimetres
    # on by default since session 8 (its grasp and update costs removed: run_labels_before_contact), an
    # addition the paper preset switches off; the fill (with or without its mask test) stays off in both
    assert PRESETS["default"].refine.contact_height == 0.002 and PRESETS["paper"].refine.contact_height == 0.0
    assert PRESETS["default"].refine.contact_fill_high == 0.0 and PRESETS["paper"].refine.contact_fill_high == 0.0


@settings(max_examples=30, deadline=None)
@given(st.lists(st.floats(-0.02, 0.05), min_size=1, max_size=40), st.floats(0.0, 0.01), st.floats(0.0, 0.01),
       st.integers(0, 1000))
def test_marked_points_grow_with_the_height_and_are_labelled(hs, a, b, seed):
    h = np.array(hs)
    inst = np.random.default_rng(seed).integers(-1, 3, len(h))
    p = at_heights(h, seed)
    lo, hi = cleared(p, inst, PLANE, min(a, b)), cleared(p, inst, PLANE, max(a, b))
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
    on = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.002, "refine.contact_fill_high": 0.0}))
    off = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.0, "refine.contact_fill_high": 0.0}))
    assert np.array_equal(on.points, off.points) and np.array_equal(on.scores, off.scores)
    changed = on.instance != off.instance
    assert changed.any()  # this scene's objects rest on the table: some contact points were labelled (measured)
    assert (on.instance[changed] == -1).all() and (off.instance[changed] >= 0).all()
    # exactly the labelled points within 2 mm of their object's support level (``contact_labels``)
    cfg = SegmentConfig()
    plane = build_supervoxels(fuse_views(scene.initial_views, cfg.pointcloud), cfg.supervoxels).plane
    res = contact_labels(off.points, off.normals, off.instance, off.num_instances, plane,
                         RefineConfig(contact_height=0.002, contact_fill_high=0.0))
    assert np.array_equal(changed, res.cleared) and not res.filled.any()
    assert np.abs(res.level).max() < 0.002  # objects on the table itself: levels within the noise of the plane
    fill = with_fields(SegmentConfig(), {"refine.contact_height": 0.003, "refine.contact_fill_low": 0.004,
                                         "refine.contact_fill_high": 0.012, "refine.contact_fill_mask_share": 0.0})
    both = segment(scene, fill)  # (the fill without its mask test: contact_labels is called without views)
    res = contact_labels(off.points, off.normals, off.instance, off.num_instances, plane, fill.refine)
    assert np.array_equal(both.instance, res.instance)


def test_clean_depth_is_left_alone():
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from tests.core.test_pipeline import small_scene

    # clean depth: the fusion keeps the plain voxels (no surface estimate), so the rule does not run,
    # even forced high enough to reach the objects' lowest points (2.3 mm above the plane, measured)
    scene = small_scene(0)
    hi = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.03}))
    assert hi.trace.surface.method == "voxel-mean"
    off = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.0, "refine.contact_fill_high": 0.0}))
    assert np.array_equal(hi.instance, off.instance)


def _box_on_floor(floor: float, seed: int = 0, noise: float = 0.001):
    """A 4 cm box (walls and top; label 0) on a floor ``floor`` metres above PLANE, with the floor
    around it (unlabelled, facing up) and the box's lowest 10 mm of wall unlabelled (what the support
    rule leaves; the walls sampled every 2.5 mm of height). Returns (points, normals, instance, heights above PLANE)."""
    rng = np.random.default_rng(seed)
    t1, t2 = np.array([1.0, 0.0, 0.0]), np.cross(N, [1.0, 0.0, 0.0])
    o = -PLANE[3] * N
    g = np.arange(-0.06, 0.0601, 0.005)
    uu, vv = np.meshgrid(g, g)
    out = (np.abs(uu) > 0.02) | (np.abs(vv) > 0.02)
    fu, fv = uu[out], vv[out]
    fh = floor + rng.normal(0, noise, fu.size)
    wall_u, wall_v, wall_h, wall_n = [], [], [], []
    s = np.arange(-0.02, 0.0201, 0.005)
    for z in np.arange(0.0, 0.04, 0.0025):
        for (u, v, nu, nv) in [(s, np.full_like(s, -0.02), 0, -1), (s, np.full_like(s, 0.02), 0, 1),
                               (np.full_like(s, -0.02), s, -1, 0), (np.full_like(s, 0.02), s, 1, 0)]:
            wall_u.append(u); wall_v.append(v); wall_h.append(np.full_like(s, floor + z)); wall_n.append(np.tile([nu, nv, 0.0], (len(s), 1)))
    wu, wv, wh = np.concatenate(wall_u), np.concatenate(wall_v), np.concatenate(wall_h)
    wn = np.concatenate(wall_n)
    tu, tv = uu[~out], vv[~out]
    th = np.full(tu.size, floor + 0.04)
    u = np.concatenate([fu, wu, tu]); v = np.concatenate([fv, wv, tv]); h = np.concatenate([fh, wh, th])
    pts = o + u[:, None] * t1 + v[:, None] * t2 + h[:, None] * N
    nrm_local = np.concatenate([np.tile([0, 0, 1.0], (fu.size, 1)), wn, np.tile([0, 0, 1.0], (tu.size, 1))])
    nrm = nrm_local[:, :1] * t1 + nrm_local[:, 1:2] * t2 + nrm_local[:, 2:] * N
    inst = np.concatenate([np.full(fu.size, -1), np.where(wh - floor < 0.0099, -1, 0), np.zeros(tu.size, int)])
    return pts, nrm, inst, h


@pytest.mark.parametrize("floor", [0.0, 0.008])
def test_contact_fill_and_clear_relative_to_the_measured_floor(floor):
    p, n, inst, h = _box_on_floor(floor)
    lvl, noise = support_levels(p, n, inst, 1, PLANE)
    assert abs(lvl[0] - floor) < 0.001 and 0.0003 < noise[0] < 0.002  # the floor around the box, its 1 mm noise
    cfg = RefineConfig(contact_height=0.003, contact_fill_low=0.004, contact_fill_high=0.012, contact_fill_mask_share=0.0)
    r = contact_labels(p, n, inst, 1, PLANE, cfg)
    rel = h - floor
    wall = (inst < 0) & (np.abs(n @ N) < 0.5)
    # the wall 4-12 mm above the floor is the box's again; the floor never is (it lies below 4 mm)
    assert (r.instance[wall & (rel >= 0.004) & (rel < 0.0115)] == 0).all()
    assert (r.instance[np.abs(n @ N) > 0.5] == np.where(h[np.abs(n @ N) > 0.5] > floor + 0.02, 0, -1)).all()
    # the wall under 4 mm stays unlabelled; nothing labelled sits under 3 mm above the floor
    assert (r.instance[wall & (rel < 0.004)] == -1).all()
    assert (rel[r.instance >= 0] >= 0.003 - 1e-9).all()
    assert np.array_equal(r.filled, (inst < 0) & (r.instance >= 0)) and not r.cleared.any()


def test_contact_labels_off_or_without_a_plane_is_the_identity():
    p, n, inst, _ = _box_on_floor(0.0)
    for cfg, plane in ((RefineConfig(contact_fill_high=0.0), PLANE),
                       (RefineConfig(contact_height=0.003, contact_fill_low=0.004, contact_fill_high=0.012), None)):
        r = contact_labels(p, n, inst, 1, plane, cfg)
        assert np.array_equal(r.instance, inst) and not r.filled.any() and not r.cleared.any()
    with pytest.raises(SceneError, match="contact_fill"):
        RefineConfig(contact_fill_low=0.01, contact_fill_high=0.5)  # metres, not millimetres


@settings(max_examples=25, deadline=None)
@given(st.integers(0, 10_000), st.floats(0.0, 0.006), st.floats(0.0, 0.006), st.floats(0.0, 0.02))
def test_contact_labels_invariants(seed, height, low, span):
    rng = np.random.default_rng(seed)
    m = 300
    p = at_heights(rng.uniform(-0.005, 0.03, m), seed) * 0.1  # a 6 cm patch: points close together
    p = p - (p @ N + PLANE[3])[:, None] * N + (p @ N + PLANE[3])[:, None] * N  # (heights keep their sign)
    n = rng.normal(size=(m, 3)); n /= np.linalg.norm(n, axis=1, keepdims=True)
    inst = rng.integers(-1, 3, m)
    cfg = RefineConfig(contact_height=height, contact_fill_low=low, contact_fill_high=low + span, contact_fill_mask_share=0.0)
    r = contact_labels(p, n, inst, 3, PLANE, cfg)
    h = p @ N + PLANE[3]
    rel = h - np.where(r.instance >= 0, r.level[np.maximum(r.instance, 0)], 0.0)
    assert ((r.instance >= 0) | (inst < 0) | r.cleared).all()  # a label is only lost by the contact rule
    assert (r.instance[inst >= 0][~r.cleared[inst >= 0]] == inst[inst >= 0][~r.cleared[inst >= 0]]).all()
    assert not (r.filled & r.cleared).any() and (inst[r.filled] < 0).all() and (inst[r.cleared] >= 0).all()
    if height > 0:
        assert (rel[r.instance >= 0] >= height - 1e-9).all()
    # a filled point took the label of an object point within the fill distance
    from scipy.spatial import cKDTree
    for k in range(3):
        f = r.filled & (r.instance == k)
        if f.any() and (inst == k).any():
            assert (cKDTree(p[inst == k]).query(p[f])[0] <= cfg.contact_fill_distance + 1e-12).all()


def test_update_state_and_grasp_target_read_the_labels_before_the_contact_rule():
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from clutt3r_core.synth.generator import SynthConfig, generate_scene
    from clutt3r_core.update.state import state_from_segmentation

    # the update's geometry must not change with the contact relabelling (sample_seq1's clamp was
    # read static with it): its state is the one of the run with the rule off, point for point
    scene = generate_scene(SynthConfig(seed=0, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    on = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.003, "refine.contact_fill_low": 0.004,
                                                      "refine.contact_fill_high": 0.012}))
    off = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.0, "refine.contact_fill_high": 0.0}))
    assert not np.array_equal(on.instance, off.instance)
    # the whole run's labels before the rule (rim voxels attached again) are the rule-off run's; the
    # update's geometry and every grasp request's target are those plus the fill's points, which
    # are the object's (session 10, ``update.geometry.run_geometry``; the planner sees the object
    # with its contact)
    from clutt3r_core.grasping.request import request_from_segmentation
    from clutt3r_core.segmentation.refine import run_labels_before_contact

    assert on.trace.surface.rim > 0  # the rim voxels are exercised
    assert np.array_equal(run_labels_before_contact(on), off.instance)
    assert np.array_equal(run_labels_before_contact(off), off.instance)
    filled = (off.instance < 0) & (on.instance >= 0)
    assert filled.any()  # the fill labelled points: the test tells
    geo = np.where(filled, on.instance, off.instance)
    s_on, s_off = state_from_segmentation(on), state_from_segmentation(off)
    n = len(s_on.instance)
    assert np.array_equal(s_on.instance, geo[:n]) and np.array_equal(s_on.points, s_off.points)
    for k in range(off.num_instances):
        assert np.array_equal(request_from_segmentation(on, k).target, geo == k)


def test_a_corrected_update_state_keeps_the_contact_with_the_corrected_ids():
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from clutt3r_core.synth.generator import SynthConfig, generate_scene
    from clutt3r_core.update.run_labels import LabelSource, RunLabels, labels_sha256
    from clutt3r_core.update.state import state_from_segmentation

    # a correction must not bring the contact's cleared points back into the update's geometry:
    # they follow their own instance's corrected id (merged: the merged id; deleted: none)
    scene = generate_scene(SynthConfig(seed=0, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    on = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.003}))
    off = segment(scene, with_fields(SegmentConfig(), {"refine.contact_height": 0.0, "refine.contact_fill_high": 0.0}))
    assert on.num_instances >= 3 and not np.array_equal(on.instance, off.instance)
    n = len(state_from_segmentation(off).instance)

    def corrected(edit):
        inst = edit(np.asarray(on.instance)).astype(np.int32)
        ids = np.unique(inst[inst >= 0]).astype(np.int32)
        return RunLabels(inst, ids, on.num_instances, LabelSource(1, 1, labels_sha256(inst)))

    merge = state_from_segmentation(on, labels=corrected(lambda a: np.where(a == 1, 0, a)))
    assert np.array_equal(merge.instance, np.where(off.instance == 1, 0, off.instance)[:n])
    delete = state_from_segmentation(on, labels=corrected(lambda a: np.where(a == 2, -1, a)))
    assert np.array_equal(delete.instance, np.where(off.instance == 2, -1, off.instance)[:n])


def test_contact_labels_leave_an_object_on_a_noisy_support_alone():
    # the floor around the box as noisy as the real sample_seq1's (7-27 mm measured): nothing changes
    p, n, inst, _ = _box_on_floor(0.0, noise=0.008)
    cfg = RefineConfig(contact_height=0.003, contact_fill_low=0.004, contact_fill_high=0.012, contact_fill_mask_share=0.0)
    r = contact_labels(p, n, inst, 1, PLANE, cfg)
    assert r.noise[0] > cfg.contact_max_noise
    assert np.array_equal(r.instance, inst) and not r.filled.any() and not r.cleared.any()
    # ... and a limit above its noise lets the rule act again
    r = contact_labels(p, n, inst, 1, PLANE, RefineConfig(contact_height=0.003, contact_fill_low=0.004,
                                                          contact_fill_high=0.012, contact_max_noise=0.05,
                                                          contact_fill_mask_share=0.0))
    assert r.filled.any()
