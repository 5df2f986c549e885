"""Rim voxels labelled after the vote (``clutt3r_core.rim``, issue 13): the attach and the pipeline."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.errors import SceneError
from clutt3r_core.pipeline import segment
from clutt3r_core.rim import RimVoxels, attach_labels


def test_attach_majority_of_the_k_nearest():
    """Points on a line at x = 0..9 cm; labels 0 0 0 1 1 -1 ... The majority of the k nearest wins,
    -1 votes like a label, and the source is the nearest voter carrying the winning label."""
    pts = np.zeros((10, 3))
    pts[:, 0] = np.arange(10) * 0.01
    lab = np.array([0, 0, 0, 1, 1, -1, -1, -1, 2, 2])
    q = np.array([[0.011, 0, 0], [0.061, 0, 0], [0.0355, 0.001, 0]])
    att = attach_labels(pts, lab, q, k=3, max_distance=1.0)
    # q0: nearest 1, 2, 0 -> 0 0 0; q1: 6, 7, 5 -> -1; q2: 4 (0.0045), 3 (0.0055), 5 -> 1 1 -1 -> 1, source 4
    assert att.label.tolist() == [0, -1, 1]
    assert att.source.tolist() == [1, 6, 4]


def test_attach_ties_go_to_the_nearest_voter():
    pts = np.array([[0.0, 0, 0], [0.01, 0, 0], [0.02, 0, 0], [0.03, 0, 0]])
    lab = np.array([5, 7, 7, 5])
    # k = 4: every point votes, 5 and 7 two votes each; the label of the nearest point wins
    att = attach_labels(pts, lab, np.array([[0.014, 0, 0], [0.016, 0, 0], [0.004, 0, 0]]), k=4, max_distance=1.0)
    assert att.label.tolist() == [7, 7, 5]
    assert att.source.tolist() == [1, 2, 0]
    # two voters, one each: the nearer one's label
    att = attach_labels(pts, lab, np.array([[0.026, 0, 0]]), k=2, max_distance=1.0)
    assert att.label.tolist() == [5] and att.source.tolist() == [3]


def test_attach_max_distance():
    """Voters farther than max_distance do not count; none within: -1, source the nearest point."""
    pts = np.array([[0.0, 0, 0], [0.005, 0, 0], [0.05, 0, 0], [0.051, 0, 0], [0.052, 0, 0]])
    lab = np.array([3, 3, 4, 4, 4])
    q = np.array([[0.004, 0, 0], [0.2, 0, 0]])
    # k = 5 without a limit: 4 wins (three votes); within 1 cm only the two 3s vote
    assert attach_labels(pts, lab, q[:1], k=5, max_distance=1.0).label.tolist() == [4]
    att = attach_labels(pts, lab, q, k=5, max_distance=0.01)
    assert att.label.tolist() == [3, -1]
    assert att.source.tolist() == [1, 4]
    assert attach_labels(pts, lab, np.zeros((0, 3)), 6, 0.02).label.shape == (0,)
    with pytest.raises(SceneError, match="k >= 1"):
        attach_labels(pts, lab, q, k=0, max_distance=0.01)
    with pytest.raises(SceneError, match="no labelled points"):
        attach_labels(np.zeros((0, 3)), np.zeros(0, int), q, k=3, max_distance=0.01)
    with pytest.raises(SceneError, match="RimVoxels.colors"):
        RimVoxels(np.zeros((2, 3)), np.zeros((2, 3)), np.zeros((2, 3)), np.ones(2))


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 40), st.integers(0, 30), st.integers(1, 8),
       st.floats(0.0, 0.05))
def test_attach_properties(seed, n, r, k, dmax):
    """Every attached label is the label of one of its voters (the k nearest within dmax) or -1
    without voters, it has the most votes among them, its source carries it; the labelled points'
    own labels are never changed (the input is not written)."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform(0, 0.05, (n, 3))
    lab = rng.integers(-1, 3, n)
    lab_in = lab.copy()
    q = rng.uniform(0, 0.05, (r, 3))
    att = attach_labels(pts, lab, q, k=k, max_distance=dmax)
    np.testing.assert_array_equal(lab, lab_in)
    kk = min(k, n)
    for i in range(r):
        d = np.linalg.norm(pts - q[i], axis=1)
        order = np.lexsort((np.arange(n), d))[:kk]
        voters = order[d[order] <= dmax]
        if len(voters) == 0:
            assert att.label[i] == -1 and att.source[i] == order[0]
            continue
        votes = {int(v): int((lab[voters] == v).sum()) for v in lab[voters]}
        assert votes[int(att.label[i])] == max(votes.values())
        assert att.source[i] in voters and lab[att.source[i]] == att.label[i]


def test_pipeline_attaches_the_rim_after_the_vote(tmp_path):
    """A tiny generated scene with RealSense-like depth: the segmentation with the rim attached is the
    one without it (same instances, scores, labels of every segmented voxel) plus the rim voxels at the
    end, each labelled as attach_labels says, in the super-voxel of its source; the trace records them."""
    from clutt3r_core.synth import SynthConfig, generate_scene

    scene = generate_scene(SynthConfig(seed=1, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    # the contact fill off in both, explicitly (off by default; on, it labels rim voxels too)
    off = segment(scene, with_fields(SegmentConfig(), {"pointcloud.surface_rim_neighbours": 0,
                                                       "refine.contact_fill_high": 0.0}))
    on = segment(scene, with_fields(SegmentConfig(), {"refine.contact_fill_high": 0.0}))
    assert on.trace.surface.method == "tsdf"
    r = on.trace.surface.rim
    n = len(off.points)
    assert r > 0 and len(on.points) == n + r and off.trace.surface.rim == 0
    np.testing.assert_array_equal(on.points[:n], off.points)
    np.testing.assert_array_equal(on.instance[:n], off.instance)
    np.testing.assert_array_equal(on.sv_labels[:n], off.sv_labels)
    np.testing.assert_array_equal(on.scores, off.scores)
    pc = on.trace.config.pointcloud
    att = attach_labels(off.points, off.instance, on.points[n:], pc.surface_rim_attach_k, pc.surface_rim_attach_distance)
    np.testing.assert_array_equal(on.instance[n:], att.label)
    np.testing.assert_array_equal(on.sv_labels[n:], off.sv_labels[att.source])
    assert (on.counts[n:] == 1).all() and on.normals.shape == on.points.shape
    assert on.trace.timing("attach") > 0
    # some rim voxels join objects (the gain is on object rims, not only the unlabelled table)
    assert (on.instance[n:] >= 0).any()
    # the run files hold the one cloud, and the trace the count of attached points
    from clutt3r_core.runs import load_run, save_run

    save_run(on, tmp_path / "run")
    back = load_run(tmp_path / "run")
    np.testing.assert_array_equal(back.points, on.points)
    np.testing.assert_array_equal(back.instance, on.instance)
    np.testing.assert_array_equal(back.sv_labels, on.sv_labels)
    assert back.trace.surface.rim == r
    # the post-grasp update's geometry leaves the rim voxels out (update/state.py says why): its
    # state is the one of the segmentation without them
    from clutt3r_core.update.state import state_from_segmentation

    st_on, st_off = state_from_segmentation(back), state_from_segmentation(off)
    np.testing.assert_array_equal(st_on.points, st_off.points)
    np.testing.assert_array_equal(st_on.instance, st_off.instance)
    np.testing.assert_array_equal(st_on.embeddings, st_off.embeddings)
