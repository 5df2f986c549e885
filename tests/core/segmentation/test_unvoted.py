"""Unvoted-cluster fallback (``segmentation.unvoted``, ours, session 8; off by default)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.config import SegmentConfig, config_from_json, config_to_json, with_fields
from clutt3r_core.errors import SceneError
from clutt3r_core.segmentation.unvoted import UnvotedConfig, unvoted_instances

PLANE = np.array([0.0, 0.0, 1.0, 0.0])  # z up, table at z = 0
ON = UnvotedConfig(min_points=20)


def _box(centre, size=0.03, step=0.005):
    """Voxel centres filling a box (a small object)."""
    ax = [np.arange(c - size / 2, c + size / 2 + 1e-9, step) for c in centre]
    return np.stack(np.meshgrid(*ax, indexing="ij"), -1).reshape(-1, 3)


def _scene():
    """A voted object, an unvoted one, a flat unvoted patch on the table, a support patch."""
    voted, unvoted = _box((0.0, 0.0, 0.025)), _box((0.2, 0.0, 0.025))
    flat = _box((0.4, 0.0, 0.0025), size=0.04)
    flat = flat[flat[:, 2] < 0.006]
    support = _box((0.6, 0.0, 0.03))
    pts = np.concatenate([voted, unvoted, flat, support]).astype(np.float32)
    n = [len(voted), len(unvoted), len(flat), len(support)]
    sv = np.repeat(np.arange(4), n)
    inst = np.where(sv == 0, 0, -1).astype(np.int32)
    return pts, np.full(len(pts), 3, np.int32), inst, sv, np.array([False, False, False, True])


def test_an_unvoted_object_above_the_table_becomes_the_last_instance():
    pts, counts, inst, sv, support = _scene()
    r = unvoted_instances(pts, counts, inst, sv, support, np.zeros(4), PLANE, np.array([0.4], np.float32), ON)
    assert r.scores.shape == (2,) and r.scores[1] < r.scores[0]
    high = pts[:, 2].astype(np.float64) >= ON.min_height  # as the function computes it
    assert (r.instance[(sv == 1) & high] == 1).all()  # the unvoted box, except its lowest layer
    assert (r.instance[(sv == 1) & ~high] == -1).all()
    assert (r.instance[sv == 0] == 0).all()  # voted labels untouched
    assert (r.instance[sv == 2] == -1).all()  # flat on the table: below min_height
    assert (r.instance[sv == 3] == -1).all()  # support super-voxel
    assert r.added_points.tolist() == [3 * int(((sv == 1) & high).sum())]
    assert r.added_height[0] == pytest.approx(pts[sv == 1, 2].max())


def test_nothing_is_added_when_off_without_a_plane_or_under_a_background_mask():
    pts, counts, inst, sv, support = _scene()
    s = np.array([0.4], np.float32)
    off = unvoted_instances(pts, counts, inst, sv, support, np.zeros(4), PLANE, s, UnvotedConfig())
    assert off.scores.shape == (1,) and (off.instance == inst).all()
    assert len(unvoted_instances(pts, counts, inst, sv, support, np.zeros(4), None, s, ON).scores) == 1
    covered = np.array([0.0, 0.9, 0.0, 0.0])  # a background (table / tray) mask covers the box
    assert len(unvoted_instances(pts, counts, inst, sv, support, covered, PLANE, s, ON).scores) == 1
    big = dataclasses.replace(ON, min_points=10_000)
    assert len(unvoted_instances(pts, counts, inst, sv, support, np.zeros(4), PLANE, s, big).scores) == 1


def test_config_is_checked_and_old_configs_load_with_it_off(tmp_path):
    with pytest.raises(SceneError):
        UnvotedConfig(min_points=-1)
    with pytest.raises(SceneError):
        UnvotedConfig(score_fraction=1.0)
    data = config_to_json(SegmentConfig())
    del data["unvoted"]
    assert config_from_json(data, tmp_path / "config.json").unvoted.min_points == 0
    assert SegmentConfig().unvoted.min_points == 0  # off by default


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(0, 4))
def test_voted_labels_stay_and_added_instances_score_below_every_voted_one(seed, k):
    rng = np.random.default_rng(seed)
    n = 300
    pts = (rng.random((n, 3)) * [0.3, 0.3, 0.08]).astype(np.float32)
    sv = rng.integers(0, 12, n)
    support = rng.random(12) < 0.3
    inst = np.where(rng.random(n) < 0.5, rng.integers(0, max(k, 1), n), -1).astype(np.int32) if k else np.full(n, -1, np.int32)
    scores = np.sort(rng.random(k).astype(np.float32) + 0.1)[::-1]
    cfg = UnvotedConfig(min_points=5, min_extent=0.0, connect_radius=0.03)
    r = unvoted_instances(pts, np.ones(n, np.int32), inst, sv, support, rng.random(12), PLANE, scores, cfg)
    assert (r.instance[inst >= 0] == inst[inst >= 0]).all()
    assert (r.scores[:k] == scores).all()
    if k and len(r.scores) > k:
        assert r.scores[k:].max() < scores.min()
    assert (np.diff(r.scores[k:]) <= 0).all()  # ids by descending score
    added = r.instance >= k
    assert not support[sv[added]].any()
    assert (pts[added, 2] >= cfg.min_height).all()
    assert sorted(np.unique(r.instance[added]).tolist()) == list(range(k, len(r.scores)))


def test_a_fallback_instance_is_its_own_grasp_target_under_the_contact_rule():
    from clutt3r_core.grasping.request import request_from_segmentation
    from clutt3r_core.pipeline import segment
    from clutt3r_core.synth.generator import SynthConfig, generate_scene

    # noisy depth: the contact rule runs, and the grasp target and the update read the labels
    # before it (refine.run_labels_before_contact), which the vote alone never gave this instance
    noisy = generate_scene(SynthConfig(seed=0, preset="easy", views=3, width=320, height=240, n_objects=3,
                                       depth_noise="realsense"), progress=False)
    seg = segment(_scene_without_object_masks(0, noisy), with_fields(SegmentConfig(), {"unvoted.min_points": 20}))
    assert seg.trace.surface.method == "tsdf" and seg.trace.config.refine.contact_height > 0
    voted = len(seg.trace.vote.instance_group)
    assert seg.num_instances > voted
    for k in range(voted, seg.num_instances):
        own = seg.instance == k
        target = request_from_segmentation(seg, k).target
        assert own.any() and (target[own]).all() and not (target & (seg.instance >= 0) & ~own).any()


def _scene_without_object_masks(obj: int, scene=None):
    """``scene`` (the tiny scene by default) with every candidate mask that is mostly object
    ``obj`` removed."""
    from clutt3r_core.scene import MaskCandidates

    from tests.core._tiny_run import tiny_scene

    scene = tiny_scene() if scene is None else scene
    views = []
    for v in scene.views:
        gt = scene.ground_truth.instance_maps.get(v.frame)
        if v.masks is None or gt is None:
            views.append(v)
            continue
        m = v.masks.masks
        own = np.array([(gt[mi] == obj).sum() > 0.5 * mi.sum() for mi in m], bool)
        sc = None if v.masks.scores is None else v.masks.scores[~own]
        views.append(dataclasses.replace(v, masks=MaskCandidates(m[~own], v.masks.ids[~own], sc)))
    return dataclasses.replace(scene, views=tuple(views))


@pytest.fixture(scope="module")
def fallback_run(tmp_path_factory):
    from clutt3r_core.pipeline import load_run, save_run, segment

    scene = _scene_without_object_masks(0)
    seg = segment(scene, with_fields(SegmentConfig(), {"unvoted.min_points": 20}))
    voted = len(seg.trace.vote.instance_group)
    assert seg.num_instances > voted, "the object without masks should come back as a fallback instance"
    from clutt3r_core.synth import write_synth_scene

    root = tmp_path_factory.mktemp("run")
    scene_dir = write_synth_scene(scene, root / "scene", contact_sheet=False)
    d = root / "run"
    save_run(seg, d, scene_root=scene_dir)
    return seg, load_run(d), d, voted


def test_a_fallback_instance_has_no_masks_and_the_lowest_score(fallback_run):
    seg, _, _, voted = fallback_run
    for k in range(voted, seg.num_instances):
        assert seg.instance_nodes(k) == ()
        assert (seg.instance == k).any()
        assert seg.scores[k] < seg.scores[:voted].min()
    with pytest.raises(IndexError):
        seg.instance_nodes(seg.num_instances)


def test_a_run_with_a_fallback_instance_saves_loads_explains_and_answers_a_query(fallback_run, capsys):
    from clutt3r_core.commands.explain import explain_command
    from clutt3r_core.query import instance_text_scores
    from clutt3r_core.query.evidence import instance_node_lists

    seg, back, d, voted = fallback_run
    assert back.num_instances == seg.num_instances
    assert (back.instance == seg.instance).all() and np.allclose(back.scores, seg.scores)
    assert back.instance_nodes(seg.num_instances - 1) == ()
    assert instance_node_lists(back)[-1] == ()
    text = back.trace.embeddings[0]
    s = instance_text_scores(back, text)
    assert s.shape == (seg.num_instances,) and (s[voted:] == -1).all()
    k = int(back.sv_labels[np.flatnonzero(back.instance == seg.num_instances - 1)[0]])
    explain_command(d, supervoxel=k)
    assert capsys.readouterr().out.strip()
    from clutt3r_core.query import RunQuery
    from tests.core.query._fake import FakeGrounder

    rq = RunQuery.open(d, grounder=FakeGrounder(), use_cache=False)
    assert rq.instances.num_instances == seg.num_instances and rq.instances.n_views[voted:].max() == 0
    res = rq.query("orange")
    assert 0 <= res.target < seg.num_instances
