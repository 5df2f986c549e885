"""Small super-voxels relabelled by their neighbourhood after the vote (``vote.smooth_small_supervoxels``)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.vote import VoteConfig, smooth_small_supervoxels

ON = VoteConfig(smooth_max_size=3, smooth_min_agree=5)


def _plane(n: int = 9, step: float = 0.005) -> np.ndarray:
    """(n*n, 3) voxel centres of a flat n x n patch at 5 mm spacing."""
    u, v = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    return np.stack([u.ravel() * step, v.ravel() * step, np.zeros(n * n)], 1).astype(np.float32)


def _patch_with_speck(speck_label: int):
    """One big super-voxel (0, instance 0) with a single-voxel super-voxel (1) in its middle."""
    pts = _plane()
    sv = np.zeros(len(pts), np.int64)
    mid = len(pts) // 2
    sv[mid] = 1
    inst = np.zeros(len(pts), np.int32)
    inst[mid] = speck_label
    return pts, inst, sv, mid


@pytest.mark.parametrize("speck", [1, -1])
def test_speck_inside_an_instance_takes_it(speck):
    # a voxel the masks' edges gave to a neighbour (1) or to nothing (-1), amid instance 0
    pts, inst, sv, mid = _patch_with_speck(speck)
    out = smooth_small_supervoxels(pts, inst, sv, np.zeros(2, bool), ON)
    assert out[mid] == 0
    assert (np.delete(out, mid) == 0).all()


def test_off_support_and_large_supervoxels_unchanged():
    pts, inst, sv, mid = _patch_with_speck(1)
    assert (smooth_small_supervoxels(pts, inst, sv, np.zeros(2, bool), VoteConfig()) == inst).all()  # off
    assert smooth_small_supervoxels(pts, inst, sv, np.array([False, True]), ON)[mid] == 1  # support speck
    # the speck grown to 4 voxels is above smooth_max_size 3
    sv4 = sv.copy()
    sv4[[mid - 1, mid + 1, mid + 9]] = 1
    inst4 = np.where(sv4 == 1, 1, 0).astype(np.int32)
    assert (smooth_small_supervoxels(pts, inst4, sv4, np.zeros(2, bool), ON) == inst4).all()


def test_never_unlabels_and_unlabelled_neighbours_block():
    # a labelled speck amid unlabelled voxels stays labelled (a -1 majority changes nothing)
    pts, inst, sv, mid = _patch_with_speck(1)
    inst = np.where(sv == 1, 1, -1).astype(np.int32)
    assert smooth_small_supervoxels(pts, inst, sv, np.zeros(2, bool), ON)[mid] == 1
    # half the neighbourhood unlabelled, half instance 2: instance 2 lacks the quorum of 5 of 10
    inst = np.where(pts[:, 0] < pts[mid, 0], 2, -1).astype(np.int32)
    inst[mid] = 1
    got = smooth_small_supervoxels(pts, inst, sv, np.zeros(2, bool), ON)[mid]
    assert got == 1


def test_neighbours_beyond_the_radius_do_not_vote():
    pts, inst, sv, mid = _patch_with_speck(1)
    far = pts.copy()
    far[mid, 2] = 0.05  # the speck 5 cm above the patch
    assert smooth_small_supervoxels(far, inst, sv, np.zeros(2, bool), ON)[mid] == 1


def test_config_checked():
    with pytest.raises(SceneError):
        VoteConfig(smooth_max_size=-1)
    with pytest.raises(SceneError):
        VoteConfig(smooth_min_agree=11, smooth_k=10)
    with pytest.raises(SceneError):
        VoteConfig(smooth_radius=0.0)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 10_000), max_size=st.integers(1, 4))
def test_invariants(seed, max_size):
    """Only small non-support super-voxels change, each as a whole, only to an instance label
    present in the input, and never from an instance to -1."""
    rng = np.random.default_rng(seed)
    pts = (rng.random((200, 3)) * 0.05).astype(np.float32)
    sv = rng.integers(0, 60, 200)
    sv_inst = rng.integers(-1, 4, 60)
    inst = sv_inst[sv].astype(np.int32)
    support = rng.random(60) < 0.2
    cfg = VoteConfig(smooth_max_size=max_size, smooth_min_agree=3)
    out = smooth_small_supervoxels(pts, inst, sv, support, cfg)
    changed = out != inst
    sizes = np.bincount(sv, minlength=60)
    assert (sizes[sv[changed]] <= max_size).all()
    assert not support[sv[changed]].any()
    assert (out[changed] >= 0).all()
    assert set(out[changed].tolist()) <= set(inst[inst >= 0].tolist())
    for k in np.unique(sv):  # a super-voxel keeps one label
        assert len(np.unique(out[sv == k])) == 1


def test_pipeline_smoothing_changes_only_small_supervoxels_and_never_the_grouping():
    """segment() with the smoothing on: the same grouping and vote, labels changed only on small
    non-support super-voxels of the segmented cloud, and only from -1 or another instance to an instance."""
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import instance_tree_json, segment
    from clutt3r_core.synth import SynthConfig, generate_scene
    from clutt3r_core.update.run_labels import fused_count

    scene = generate_scene(SynthConfig(seed=1, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       mask_noise="grounded-sam-like", depth_noise="realsense"), progress=False)
    # the contact fill off in both, explicitly (off by default; it reads the labels, so it would follow them)
    off = segment(scene, with_fields(SegmentConfig(), {"refine.contact_fill_high": 0.0}))
    on = segment(scene, with_fields(SegmentConfig(), {"vote.smooth_max_size": 3, "vote.smooth_min_agree": 5,
                                                      "refine.contact_fill_high": 0.0}))
    assert instance_tree_json(off) == instance_tree_json(on)
    assert np.array_equal(off.trace.vote.sv_label, on.trace.vote.sv_label)
    n = fused_count(off)
    changed = np.flatnonzero(off.instance[:n] != on.instance[:n])
    assert len(changed)  # 10 of 45 k voxels on this scene: the rule runs in the pipeline
    sizes = np.bincount(off.sv_labels[:n])
    assert (sizes[off.sv_labels[changed]] <= 3).all()
    assert not off.sv_support[off.sv_labels[changed]].any()
    assert (on.instance[changed] >= 0).all()


def test_labels_before_the_contact_rule_include_the_smoothing():
    """With the smoothing and the contact rule both on, the labels the update and the grasp target
    read (``refine.run_labels_before_contact``) are the run's with the contact rule off: smoothed."""
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment
    from clutt3r_core.segmentation.refine import run_labels_before_contact
    from clutt3r_core.synth import SynthConfig, generate_scene

    scene = generate_scene(SynthConfig(seed=1, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       mask_noise="grounded-sam-like", depth_noise="realsense"), progress=False)
    smooth = {"vote.smooth_max_size": 3, "vote.smooth_min_agree": 5}
    on = segment(scene, with_fields(SegmentConfig(), smooth))
    no_contact = segment(scene, with_fields(SegmentConfig(), {**smooth, "refine.contact_height": 0.0,
                                                              "refine.contact_fill_high": 0.0}))
    assert not np.array_equal(on.instance, no_contact.instance)  # the contact rule ran
    assert np.array_equal(run_labels_before_contact(on), no_contact.instance)
