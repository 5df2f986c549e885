"""The objects' geometry with the rules that trim the shown labels switched on (session 10,
``update.geometry.run_geometry``).

The run shows its labels after the weak-echo rule (``refine.weak_echo_ratio``, off by default) and
the contact rule (``refine.contact_labels``: lowest ~2 mm cleared, and with ``contact_fill_low`` /
``_high``, off by default, the object's lowest walls filled). The update's state, the grasp target
and the scenes after updates read the geometry instead: the labels before both trimming rules,
with the fill's points (they are the object's, confirmed by its masks). Before session 10 the
geometry was the labels before the contact rule only: with the echo rule on, the flanks it cleared
were no part of their object (the grasp target lost them, an update left them behind), and with the
fill on, a displaced object's filled walls stayed where it had been, unlabelled.

The scene: a tiny generated easy scene with RealSense-like depth (seed 14, 3 views at 320 x 240,
4 objects; the echo rule at 0.2 clears 9 points the vote labelled, of I0 and I1; the fill fills 9
points of I1 and 4 of I2), segmented once per config.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from clutt3r_core.annotations import Annotations, Merge
from tests.core.update.test_scene_after_geometry import _chain  # one saved update of a run

SEED = 14
ECHO = {"refine.weak_echo_ratio": 0.2}
FILL = {"refine.contact_fill_low": 0.004, "refine.contact_fill_high": 0.012}


@pytest.fixture(scope="module")
def scene():
    from clutt3r_core.synth.generator import SynthConfig, generate_scene

    return generate_scene(SynthConfig(seed=SEED, preset="easy", views=3, width=320, height=240, n_objects=3,
                                      depth_noise="realsense"), progress=False)


@pytest.fixture(scope="module")
def segs(scene):
    """{name: Segmentation} of the scene: the default config (echo and fill off), the echo rule on
    (with and without the contact rule), the fill on, both on."""
    from clutt3r_core.config import SegmentConfig, with_fields
    from clutt3r_core.pipeline import segment

    cfgs = {"off": {}, "echo": ECHO, "echo_alone": {**ECHO, "refine.contact_height": 0.0}, "fill": FILL,
            "echo_fill": {**ECHO, **FILL}}
    return {name: segment(scene, with_fields(SegmentConfig(), f)) for name, f in cfgs.items()}


def _filled(seg) -> np.ndarray:
    """(N,) bool the points the contact fill labelled: unlabelled before the rule, an object's after it."""
    from clutt3r_core.segmentation.refine import run_labels_before_contact

    return (np.asarray(run_labels_before_contact(seg)) < 0) & (seg.instance >= 0)


def test_default_config_geometry_is_the_labels_before_the_contact_rule(segs):
    """Echoes and fill off (the default): the geometry is what it was, exactly."""
    from clutt3r_core.segmentation.refine import run_labels_before_contact
    from clutt3r_core.update.geometry import run_geometry

    seg = segs["off"]
    assert not _filled(seg).any()
    np.testing.assert_array_equal(run_geometry(seg), run_labels_before_contact(seg))


@pytest.mark.parametrize("name", ["echo", "echo_alone"])
def test_the_geometry_holds_the_points_the_echo_rule_cleared(segs, name):
    """With the echo rule on, the geometry is the one of the run with it off, point for point (the
    rule acts after the vote, so nothing else changes), and so are the update's state and every grasp
    target; the shown labels keep the rule's output (the echoes unlabelled)."""
    from clutt3r_core.grasping.request import request_from_segmentation
    from clutt3r_core.segmentation.refine import run_labels_before_contact, weak_echoes
    from clutt3r_core.update.geometry import fused_count, geometry_labels, run_geometry
    from clutt3r_core.update.state import state_from_segmentation

    on, off = segs[name], segs["off"]
    want = run_labels_before_contact(off)  # neither rule: the echo rule is off, the contact rule undone
    geo = run_geometry(on)
    n = fused_count(on)
    echo = np.zeros(len(on.points), bool)
    echo[:n] = weak_echoes(on.points[:n], on.normals[:n], on.counts[:n], on.trace.config.pointcloud.voxel_size,
                           ECHO["refine.weak_echo_ratio"])
    held = echo & (want >= 0)  # flanks the vote labelled
    assert held.sum() >= 3, f"the echo rule cleared too few labelled points ({held.sum()}): the test tells nothing"
    assert (on.instance[held] < 0).all()  # the shown labels: cleared
    np.testing.assert_array_equal(geo[held], want[held])  # the geometry: their object's
    np.testing.assert_array_equal(geo, want)
    assert (run_labels_before_contact(on)[held] < 0).all()  # what the geometry read before session 10
    np.testing.assert_array_equal(state_from_segmentation(on).instance, state_from_segmentation(off).instance)
    for k in range(on.num_instances):
        np.testing.assert_array_equal(request_from_segmentation(on, k).target, want == k)
    # a correction carries the cleared flanks with their instance: merged into another id, they are its
    a, b = 0, 1
    merged = np.where(on.instance == b, a, on.instance).astype(np.int32)
    np.testing.assert_array_equal(geometry_labels(on, merged), np.where(want == b, a, want))


def test_with_both_rules_on_the_geometry_holds_the_echoes_and_the_filled_walls(segs):
    """Echo rule and fill on: the geometry is the rule-off run's labels before the contact rule with
    the fill's points added (those the vote left unlabelled), nothing else."""
    from clutt3r_core.segmentation.refine import run_labels_before_contact
    from clutt3r_core.update.geometry import run_geometry

    on = segs["echo_fill"]
    want = run_labels_before_contact(segs["off"])
    filled = _filled(on) & (want < 0)
    assert filled.any() and ((want >= 0) & (on.instance < 0)).any()
    np.testing.assert_array_equal(run_geometry(on), np.where(filled, on.instance, want))


@pytest.fixture
def fill_run(segs, tmp_path):
    from clutt3r_core.runs import save_run

    return save_run(segs["fill"], tmp_path / "run")


def test_a_displaced_objects_filled_walls_move_with_it(segs, fill_run):
    """Fill on, one object displaced and one removed by an update: the filled points are their
    objects' geometry at step 0 (grasp target, state), move with the displaced one (none left at the
    old place, shown and targeted as its own there) and leave with the removed one."""
    from scipy.spatial import cKDTree

    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_core.update.geometry import fused_count, run_geometry
    from clutt3r_core.update.scene_after import scene_after
    from clutt3r_core.update.state import state_from_run

    seg = segs["fill"]
    filled = _filled(seg)
    per = np.bincount(seg.instance[filled], minlength=seg.num_instances)
    moved, removed = (int(k) for k in np.argsort(-per, kind="stable")[:2])
    assert per[moved] >= 3 and per[removed] >= 1, f"the fill labelled too few points ({per}): the test tells nothing"
    fm, fr = filled & (seg.instance == moved), filled & (seg.instance == removed)
    geo = run_geometry(seg)
    np.testing.assert_array_equal(geo[filled], seg.instance[filled])
    # step 0: the fill's points are in the grasp target and the update's state
    assert request_from_run(fill_run, moved, step=0)[0].target[fm].all()
    n = fused_count(seg)
    s0 = state_from_run(fill_run)
    np.testing.assert_array_equal(s0.instance[filled[:n]], seg.instance[:n][filled[:n]])

    _, T = _chain(fill_run, (0.05, 0.02, 0.0), moved, removed)  # one saved update
    sa = scene_after(fill_run, 1, seg=seg)
    want = seg.points[fm].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    np.testing.assert_allclose(sa.run_points[fm], want, atol=1e-6)  # moved with the object
    assert (sa.run_instance[fm] == moved).all() and (sa.run_geometry[fm] == moved).all()
    assert cKDTree(sa.points).query(seg.points[fm])[0].min() > 1e-4  # nothing left where they were
    assert sa.gone[fr].all()  # left with the removed object
    rows = np.flatnonzero(~sa.gone)  # the scene's rows of the run's points
    assert sa.grasp_target(moved)[np.searchsorted(rows, np.flatnonzero(fm))].all()
    req = request_from_run(fill_run, moved, step=1)[0]
    np.testing.assert_array_equal(req.target, sa.grasp_target(moved))


def test_a_merge_carries_the_filled_walls_to_the_merged_id(segs, fill_run):
    """Corrected ids (the Edit tab merged the two filled objects): the fill's points of both are the
    merged id's geometry at step 0, and the update's state holds them so."""
    from clutt3r_core.update.geometry import fused_count
    from clutt3r_core.update.run_labels import step_zero_labels
    from clutt3r_core.update.state import state_from_run

    seg = segs["fill"]
    filled = _filled(seg)
    per = np.bincount(seg.instance[filled], minlength=seg.num_instances)
    a, b = (int(k) for k in np.argsort(-per, kind="stable")[:2])
    with Annotations.open(fill_run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=a, other=b))
    z = step_zero_labels(seg, fill_run)
    assert z.corrected
    both = filled & np.isin(seg.instance, [a, b])
    assert (z.geometry[both] == a).all() and z.target(a)[both].all()
    n = fused_count(seg)
    np.testing.assert_array_equal(state_from_run(fill_run).instance, z.geometry[:n])


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(["merge", "delete"]))
def test_a_correction_carries_cleared_and_filled_points_with_their_instance(seed, edit):
    """Property (``corrected_geometry_labels`` over any geometry and shown labels): the shown labels
    are the geometry with some points cleared (echoes, contact) and some unlabelled points filled (the
    fill, which the geometry holds); after the Edit tab merges instance b into a, the corrected
    geometry is the geometry with b's points a's, cleared and filled ones included; after it deletes
    b, b's points are none and every other point keeps its geometry id (rim voxels included)."""
    from types import SimpleNamespace

    from clutt3r_core.update.geometry import corrected_geometry_labels

    rng = np.random.default_rng(seed)
    n, k = 80, 4
    geo = rng.integers(-1, k, n).astype(np.int32)
    geo[:k] = np.arange(k)  # every instance keeps a shown point (the cleared ones' nearest source)
    shown = geo.copy()
    cleared = (rng.random(n) < 0.25) & (geo >= 0)
    cleared[:k] = False
    shown[cleared] = -1
    filled = rng.random(n) < 0.1  # the fill's points: an instance's in the shown labels and the geometry
    filled[:k] = False
    shown[filled] = geo[filled] = rng.integers(0, k, int(filled.sum()))
    seg = SimpleNamespace(points=rng.normal(size=(n, 3)), instance=shown,
                          trace=SimpleNamespace(surface=SimpleNamespace(rim=int(rng.integers(0, 20)))))
    a, b = (int(x) for x in rng.choice(k, 2, replace=False))
    into = a if edit == "merge" else -1
    corrected = np.where(shown == b, into, shown).astype(np.int32)
    got = corrected_geometry_labels(seg, corrected, n, geo)
    np.testing.assert_array_equal(got, np.where(geo == b, into, geo))
