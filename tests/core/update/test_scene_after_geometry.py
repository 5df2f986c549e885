"""After an update the grasp target is the object's whole extent too (session 9,
``update.run_labels.geometry_labels`` / ``SceneAfter.grasp_target``).

On noisy depth the run leaves each object's lowest ~2 mm unlabelled (``refine.contact_labels``).
The update's state holds the labels before that rule (``state._geometry_labels``), and the grasp
target at step 0 reads them (``run_labels.StepZeroLabels.geometry``). The scene after an update
(``SceneAfter``) must read them as well: the target of a static instance is its pre-contact points,
a displaced one's are moved by the update's motion, a removed one's leave with it, and the scene's
run points of every instance are the state's points of it. ``grasps.json`` at step > 0 records the
correction log state the chain was computed from, as at step 0.

The scene: a tiny generated easy scene with RealSense-like depth (seed 11, 3 objects: the contact
rule clears 6 points of I1 and 1 of I2, one of them a rim voxel), segmented once per module; the
updates are written through the core's API (``apply_update`` / ``save_state``).
"""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from clutt3r_core.annotations import Annotations, Merge, Split
from clutt3r_core.errors import SceneError
from tests.core.update._scenes import noisy_contact_run


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    run, seg, pre = noisy_contact_run(tmp_path_factory.mktemp("sa_geo"), seed=11)
    cleared = np.bincount(pre[(pre >= 0) & (seg.instance < 0)], minlength=seg.num_instances)
    assert (cleared > 0).sum() >= 2, f"the contact rule cleared points of too few instances ({cleared})"
    return run, seg, pre, cleared


@pytest.fixture
def run(base, tmp_path):
    from tests.core.query._fake import copy_run

    return copy_run(base[0], base[0].parent, tmp_path / "run")


def _roles(cleared) -> tuple[int, int, int]:
    """(static, displaced, removed): the two instances with the most cleared points stay and move."""
    order = [int(k) for k in np.argsort(-cleared, kind="stable")]
    return order[0], order[1], order[2]


def _chain(run, shift=(0.05, 0.0, 0.0), moved=None, removed=None):
    """One saved update of the run's state: ``moved`` displaced by ``shift`` (a yaw too), ``removed`` gone."""
    from clutt3r_core.update import InstanceUpdate, UpdateResult
    from clutt3r_core.update.state import apply_update, save_state, state_from_run

    s0 = state_from_run(run)
    T = np.eye(4)
    c, s = np.cos(0.3), np.sin(0.3)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = shift
    recs = tuple(InstanceUpdate(int(k), "displaced", 0.5, 0.9, T) if k == moved else
                 InstanceUpdate(int(k), "removed", None, None, None) if k == removed else
                 InstanceUpdate(int(k), "static", 0.9, 0.9, None) for k in s0.instance_ids)
    r = UpdateResult(8, recs, (), np.zeros((len(recs), 4, 4), bool), np.full((4, 4), -1, np.int32), 0.1)
    s1 = apply_update(s0, r)
    save_state(s1, run / "updates" / "01_frame_000008", r)
    return s1, T


def _rows(a: np.ndarray) -> np.ndarray:
    """The rows of (P, 3) ``a`` sorted lexicographically (to compare point sets)."""
    a = np.asarray(a, np.float64)
    return a[np.lexsort(a.T[::-1])]


def test_the_target_after_an_update_is_the_pre_contact_extent(run, base):
    """Fails on 2344491: the target after the update was ``instance == k`` of the contact rule's
    labels (the static instance lost its cleared points, the displaced one left them behind)."""
    from clutt3r_core.grasping.request import request_from_run

    _, seg, pre, cleared = base
    static, moved, removed = _roles(cleared)
    _, T = _chain(run, moved=moved, removed=removed)
    pts = seg.points.astype(np.float64)
    for k, want in ((static, pts[pre == static]), (moved, pts[pre == moved] @ T[:3, :3].T + T[:3, 3])):
        req = request_from_run(run, k, step=1)[0]
        assert ((pre == k) != (seg.instance == k)).any()  # the contact rule changed k's points: the test tells
        assert req.target.sum() == (pre == k).sum()
        np.testing.assert_allclose(_rows(req.points[req.target]), _rows(want), atol=1e-6)
    with pytest.raises(SceneError, match="removed by update 1"):
        request_from_run(run, removed, step=1)


def test_the_scene_moves_and_removes_what_the_state_moved_and_removed(run, base):
    """The scene's run points of each instance (fused points, by the labels before the contact rule)
    are the state's points of it; a removed instance's cleared points leave with it (fails on 2344491:
    the contact points of a displaced object stayed where it was, unlabelled)."""
    from clutt3r_core.update.run_labels import fused_count
    from clutt3r_core.update.scene_after import scene_after

    _, seg, pre, cleared = base
    static, moved, removed = _roles(cleared)
    s1, _ = _chain(run, moved=removed, removed=moved)  # the other way round: an instance with cleared points removed
    sa = scene_after(run, 1, seg=seg)
    n = fused_count(seg)
    np.testing.assert_array_equal(sa.gone, pre == moved)  # its cleared points too
    fused = np.zeros(len(sa.run_points), bool)
    fused[:n] = True
    for k in s1.instance_ids.tolist():
        got = sa.run_points[fused & (pre == k) & ~sa.gone]
        np.testing.assert_allclose(_rows(got), _rows(s1.points_of(k)), atol=1e-6)
    # what is left unlabelled in the scene is left in place: no instance's strip of contact points
    rest = fused & (pre < 0)
    np.testing.assert_array_equal(sa.run_points[rest], seg.points[rest])
    assert np.array_equal(sa.instance, sa.run_instance[~sa.gone])  # the labels shown stay the contact rule's
    np.testing.assert_array_equal(sa.run_geometry, pre)  # the run's own ids: exactly the labels before the rule


def test_a_chain_whose_state_holds_the_contact_labels_keeps_its_scene(run, base):
    """A state written by an older version (its run rows labelled by the contact rule): the scene is
    the one it always was (one labelling), not the recomputed geometry the chain never moved."""
    from clutt3r_core.update.run_labels import fused_count
    from clutt3r_core.update.scene_after import chain_inputs, scene_after
    from clutt3r_core.update.state import load_state, save_state

    _, seg, pre, cleared = base
    static, moved, _ = _roles(cleared)
    _chain(run, moved=moved)
    d = run / "updates" / "01_frame_000008"
    s1 = load_state(d)
    n = fused_count(seg)
    old = np.array(s1.instance)
    old[:n] = seg.instance[:n]  # nothing removed: the run rows are the fused points in order
    save_state(replace(s1, instance=old), d)
    assert chain_inputs(run, 1, seg=seg).geometry is chain_inputs(run, 1, seg=seg).instance
    sa = scene_after(run, 1, seg=seg)
    assert sa.grasp_target(static).sum() == (seg.instance == static).sum()


def test_a_corrected_chain_records_its_log_state_and_targets_the_merged_extent(run, base, capsys):
    """Merge before the update: the target of the merged id after the update is its target before it
    (both parts' points before the contact rule, ``StepZeroLabels.target``), and grasps.json / --json record the chain's log state at step 1 as at step 0
    (fails on 2344491: no "corrections" at step > 0)."""
    from clutt3r_core.commands.grasp import grasp_command
    from clutt3r_core.update.run_labels import step_zero_labels
    from clutt3r_core.update.scene_after import chain_inputs, scene_after
    from clutt3r_core.update.state import load_state

    _, seg, pre, cleared = base
    static, moved, removed = _roles(cleared)
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=static, other=moved))
    want = step_zero_labels(seg, run).target(static)  # the target before the update (both parts, pre-contact)
    _chain(run, moved=None, removed=removed)
    grasp_command(run, instance=static, json=True, top=3, step=1)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    src = load_state(run / "updates" / "01_frame_000008").labels
    assert out["step"] == 1 and out["corrections"] == src.to_json() and src.entries == 1
    assert json.loads((run / "grasps.json").read_text())["corrections"] == src.to_json()
    from clutt3r_core.grasping.request import request_from_run

    req = request_from_run(run, static, step=1)[0]
    assert (want != np.isin(seg.instance, [static, moved])).any()  # not the contact rule's labels: the test tells
    np.testing.assert_array_equal(req.target, want[~scene_after(run, 1, seg=seg).gone])  # static: as before it
    with pytest.raises(SceneError):
        request_from_run(run, moved, step=1)  # merged away: not in the chain's labelling
    inp = chain_inputs(run, 1, seg=seg)
    assert inp.geometry is not inp.instance  # the state's labels were reproduced (else it falls back)


def test_a_chain_without_corrections_records_none(run, base, capsys):
    from clutt3r_core.commands.grasp import grasp_command

    _, seg, pre, cleared = base
    static, moved, _ = _roles(cleared)
    _chain(run, moved=moved)
    grasp_command(run, instance=static, json=True, top=3, step=1)
    out = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert out["step"] == 1 and "corrections" not in out


def _rot_z(a: float, t) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    T[:3, 3] = t
    return T


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000), st.integers(1, 3))
def test_build_scene_after_moves_and_removes_by_the_geometry(seed, n_updates):
    """Property (pure ``build_scene_after``): for any two labellings (shown / geometry) and any chain
    of motions and removals, every point moves with its geometry instance's composed motion, is gone
    exactly when that instance was removed, the target is the geometry's, and a point the shown
    labels give a moved or removed instance its geometry does not give it reads -1."""
    from clutt3r_core.update.scene_after import ChainInputs, build_scene_after, compose_motions
    from clutt3r_core.update.state import HistoryEntry

    rng = np.random.default_rng(seed)
    n, k = 60, 4
    geo = rng.integers(-1, k, n).astype(np.int32)
    shown = np.where(rng.random(n) < 0.2, rng.integers(-1, k, n), geo).astype(np.int32)
    pts = rng.normal(size=(n, 3)).astype(np.float32)
    hist, removed = [], set()
    for u in range(n_updates):
        alive = [i for i in range(k) if i not in removed]
        disp = [i for i in alive if rng.random() < 0.5]
        gone = [i for i in alive if i not in disp and rng.random() < 0.3]
        removed |= set(gone)
        hist.append(HistoryEntry(u + 1, 8 + u, tuple(gone), tuple(disp),
                                 np.stack([_rot_z(rng.normal(), rng.normal(size=3)) for _ in disp])
                                 if disp else np.zeros((0, 4, 4))))
    inp = ChainInputs(points=pts, colors=np.zeros((n, 3), np.uint8), normals=np.tile([0, 0, 1], (n, 1)),
                      instance=shown, ids=np.arange(k), num_ids=k, history=tuple(hist), n_updates=n_updates,
                      geometry=geo)
    sa = build_scene_after(inp)
    M = compose_motions([zip(h.displaced, h.T_world) for h in hist], k)[-1]
    want = np.array([M[g, :3, :3] @ p + M[g, :3, 3] if g >= 0 else p for g, p in zip(geo, pts.astype(np.float64))])
    np.testing.assert_allclose(sa.run_points, want, atol=1e-5)
    np.testing.assert_array_equal(sa.gone, np.isin(geo, list(removed)))
    moved = {i for h in hist for i in h.displaced}
    stray = (shown >= 0) & (shown != geo) & np.isin(shown, list(moved | removed)) & ~sa.gone
    np.testing.assert_array_equal(sa.run_instance, np.where(stray, -1, shown))
    for i in sa.present.tolist():
        np.testing.assert_array_equal(sa.grasp_target(i), sa.geometry == i)
        assert np.array_equal(sa.geometry, geo[~sa.gone])


@pytest.mark.parametrize("share", [0.01, 0.05])
def test_a_split_gives_one_geometry_at_step_zero_and_after_updates(run, base, share):
    """Split off an instance's lowest points (the Edit tab): the step-0 grasp target's labels
    (``StepZeroLabels.geometry``) are the update state's labels of the fused points and the scene's
    after an update, point for point (reviewer, session 9: on 2344491..8576217 one fused point of
    seed 11 was I3 at step 0 and I2 in the state, the step-0 map searched the rim voxels too)."""
    from clutt3r_core.update.run_labels import fused_count, step_zero_labels
    from clutt3r_core.update.scene_after import chain_inputs
    from clutt3r_core.update.state import state_from_run

    _, seg, pre, cleared = base
    k = 2
    own = np.flatnonzero(seg.instance == k)
    low = own[np.argsort(seg.points[own, 2], kind="stable")[:max(1, int(round(share * len(own))))]]
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Split(points=tuple(low.tolist()), source=k))
    z = step_zero_labels(seg, run)
    assert z.corrected
    n = fused_count(seg)
    s0 = state_from_run(run)
    np.testing.assert_array_equal(z.geometry[:n], s0.instance)  # the state's rows are the fused points, in order
    _chain(run)  # an update that changes nothing: the scene after it holds step 0's geometry
    inp = chain_inputs(run, 1, seg=seg)
    assert inp.geometry is not inp.instance  # the state's labels were reproduced (else it falls back)
    np.testing.assert_array_equal(inp.geometry, z.geometry)


def test_a_merged_id_after_an_update_names_the_id_it_joined(run, base):
    """At step 0 a merged id is refused naming the id it joined (``StepZeroLabels.check_target``);
    after an update the same (review 13; before: "does not exist in the scene after update 1")."""
    from clutt3r_core.grasping.request import request_from_run

    _, seg, pre, cleared = base
    static, moved, removed = _roles(cleared)
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=static, other=moved))
    _chain(run, moved=None, removed=removed)
    with pytest.raises(SceneError, match=f"I{moved} was merged into I{static} .* entry 1"):
        request_from_run(run, moved, step=1)
    with pytest.raises(SceneError, match="removed by update 1"):  # a removed id keeps its reason
        request_from_run(run, removed, step=1)
    with pytest.raises(SceneError, match="does not exist"):
        request_from_run(run, 99, step=1)
