"""End-to-end tests of segment() on tiny generated scenes and on the real samples."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.evaluation.metrics import evaluate_instances
from clutt3r_core.pipeline import PRESETS, instance_tree_json, load_run, save_run, segment
from clutt3r_core.scene import MaskCandidates, Scene
from clutt3r_core.segmentation.compare import leaf_pair_agreement
from clutt3r_core.synth import SynthConfig, generate_scene

_CACHE: dict = {}


def small_scene(seed: int = 0, mask_noise: str = "grounded-sam-like") -> Scene:
    key = (seed, mask_noise)
    if key not in _CACHE:
        _CACHE[key] = generate_scene(
            SynthConfig(seed=seed, preset="easy", views=3, width=320, height=240, n_objects=3, mask_noise=mask_noise),
            progress=False,
        )
    return _CACHE[key]


def permuted(scene: Scene, view_perm, mask_seed: int) -> Scene:
    """The same scene with views reordered and every view's masks shuffled (ids kept)."""
    rng = np.random.default_rng(mask_seed)
    views = []
    for v in scene.views:
        if v.masks is not None and len(v.masks):
            p = rng.permutation(len(v.masks))
            v = replace(v, masks=MaskCandidates(v.masks.masks[p], v.masks.ids[p]))
        views.append(v)
    order = list(view_perm)
    new_views = tuple(views[i] for i in order)
    where = {old: new for new, old in enumerate(order)}
    return Scene(new_views, tuple(where[i] for i in scene.initial), tuple(where[i] for i in scene.post),
                 scene.ground_truth, scene.name)


def test_clean_masks_recover_every_object():
    scene = small_scene(0, "clean")
    seg = segment(scene)
    gt = scene.ground_truth
    ap, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
    assert ap.num_gt == 3 and seg.num_instances == 3
    assert ap.ap25 == pytest.approx(100.0)
    # each instance is one object: nearly all its points lie on a single ground-truth object
    from scipy.spatial import cKDTree

    _, idx = cKDTree(gt.points).query(seg.points)
    owners = set()
    for k in range(seg.num_instances):
        lab = gt.point_labels[idx[seg.instance == k]]
        top = np.bincount(lab[lab >= 0], minlength=3)
        assert top.max() >= 0.95 * len(lab)
        owners.add(int(top.argmax()))
    assert owners == {0, 1, 2}
    # instances are sorted by descending confidence and every id has points
    assert np.all(np.diff(seg.scores) <= 0)
    assert set(np.unique(seg.instance[seg.instance >= 0])) == set(range(seg.num_instances))


def test_trace_is_complete_and_consistent():
    scene = small_scene(1)
    seg = segment(scene)
    t = seg.trace
    assert len(t.trees) == len(scene.initial)
    u = len(t.nodes)
    assert t.s_spatial.shape == (u, u) and t.occupancy.shape[0] == u and t.embeddings.shape[0] == u
    # no edges inside a view
    same = t.nodes.view[:, None] == t.nodes.view[None, :]
    assert np.all(np.isnan(t.s_spatial[same]))
    # replaying every event gives the final groups; no group holds two masks of a view
    assert t.groups_at(len(t.grouping.events)) == sorted(t.grouping.groups, key=lambda g: g[0])
    # until fragment absorption (which joins a fragment to the instance it is part of, after the
    # grouping, so two masks of one view may then share an instance) no group holds two masks of a view
    from clutt3r_core.segmentation.refine import ABSORB_STAGE

    events = t.grouping.events
    n_grouped = next((n for n, (kind, idx) in enumerate(events)
                      if kind == "merge" and t.grouping.merges[idx].stage == ABSORB_STAGE), len(events))
    # (near-identical copies of one mask, joined as one by the "duplicate" merges, take one view slot)
    copy_of = {}
    for m in t.grouping.merges:
        if m.stage == "duplicate":
            for i in m.a + m.b:
                copy_of[int(i)] = min(m.a + m.b)
    for g in t.groups_at(n_grouped):
        slots = {copy_of.get(int(i), int(i)) for i in g}
        views = t.nodes.view[sorted(slots)]
        assert len(set(views.tolist())) == len(views)
    # the grouping's merges pass their stage's threshold (stage 1 tau_spat, stage 2 tau_sem)
    for m in t.grouping.merges:
        if m.stage in ("spatial", "semantic"):
            assert m.score >= (0.5 if m.stage == "spatial" else 0.65)
    stages = [x.stage for x in t.timings]
    assert {"pointcloud", "supervoxels", "trees", "grouping", "vote"} <= set(stages)
    assert t.embedder == "appearance-hsv"


@settings(max_examples=4, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(perm=st.permutations([0, 1, 2]), mask_seed=st.integers(0, 1000))
def test_result_does_not_depend_on_mask_or_view_order(perm, mask_seed):
    scene = small_scene(2)
    ref = _CACHE.get(("ref", 2))
    if ref is None:
        ref = _CACHE[("ref", 2)] = segment(scene)
    got = segment(permuted(scene, perm, mask_seed))
    np.testing.assert_array_equal(got.instance, ref.instance)
    np.testing.assert_array_equal(got.scores, ref.scores)
    assert got.trace.grouping.groups == ref.trace.grouping.groups


def test_run_round_trip(tmp_path):
    scene = small_scene(1)
    seg = segment(scene)
    save_run(seg, tmp_path / "run")
    back = load_run(tmp_path / "run")
    np.testing.assert_array_equal(back.instance, seg.instance)
    np.testing.assert_array_equal(back.points, seg.points)
    np.testing.assert_array_equal(back.scores, seg.scores)
    assert back.trace.grouping.merges == seg.trace.grouping.merges
    assert back.trace.grouping.events == seg.trace.grouping.events
    np.testing.assert_allclose(back.trace.occupancy, seg.trace.occupancy, atol=0)
    np.testing.assert_array_equal(back.trace.s_spatial, seg.trace.s_spatial)
    tree = json.loads((tmp_path / "run" / "instance_tree.json").read_text())
    assert tree["schema_version"] == 1
    listed = {(e["frame"], e["mask"]) for e in tree["initial"]["leaf2inst"]}
    n = seg.trace.nodes
    assert listed == {n.key(i) for i in np.flatnonzero(n.is_leaf)}
    # the PLY carries one vertex per point
    head = (tmp_path / "run" / "instances.ply").read_bytes()[:300].decode(errors="ignore")
    assert f"element vertex {len(seg.points)}" in head


def test_ablation_presets_change_the_grouping():
    scene = small_scene(3)
    full = segment(scene, PRESETS["default"])
    nosub = segment(scene, PRESETS["no-substitution"])
    nospat = segment(scene, PRESETS["no-spatial"])
    assert nosub.trace.grouping.substitutions == ()
    assert all(m.stage == "semantic" for m in nospat.trace.grouping.merges)
    assert full.trace.grouping.merges[0].stage == "spatial"


def test_missing_masks_or_depth_is_a_clear_error():
    scene = small_scene(0)
    v = scene.views[scene.initial[0]]
    no_masks = Scene(tuple(replace(x, masks=None) if x is v else x for x in scene.views), scene.initial)
    with pytest.raises(SceneError, match="no mask candidates"):
        segment(no_masks, masks="scene")  # the default, masks="auto", generates them (tests/core/masks/test_ensure.py)
    no_depth = Scene(tuple(replace(x, depth=None) if x is v else x for x in scene.views), scene.initial)
    with pytest.raises(SceneError, match="no depth"):
        segment(no_depth)


def test_a_view_with_no_masks_is_fine():
    scene = small_scene(0, "clean")
    v = scene.views[scene.initial[0]]
    emptied = Scene(
        tuple(replace(x, masks=MaskCandidates.empty(*x.masks.shape)) if x is v else x for x in scene.views),
        scene.initial, (), scene.ground_truth,
    )
    seg = segment(emptied)
    assert len(seg.trace.trees[0].mask_ids) == 0
    assert seg.num_instances >= 1


@pytest.mark.realdata
@pytest.mark.parametrize("name, floor", [("sample_seq1", 0.93), ("sample_seq4", 0.85)])
def test_real_samples_agree_with_the_original_grouping(name, floor, request):
    from clutt3r_core.io import load_scene

    d = request.getfixturevalue("seq1_dir" if name == "sample_seq1" else "seq4_dir")
    seg = segment(load_scene(d))
    agree = leaf_pair_agreement(instance_tree_json(seg), d / "instance_tree.json")
    # measured 0.959 (seq1) and 0.881 (seq4) when written; the floor guards against regressions
    assert agree.f1 >= floor
    assert seg.num_instances >= 8
