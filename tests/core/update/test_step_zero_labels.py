"""Corrections reach the query and the grasps at step 0 (session 9, ``update.run_labels.step_zero_labels``).

The Edit tab's corrections (merge, split, delete) are in the run's log; before any update
``clutt3r query`` / ``clutt3r grasp`` (and ``grasping.request.request_from_run``,
``query.RunQuery.open``) must act on the corrected ids, the grasp target with the geometry before
the contact rule (``refine.run_labels_before_contact``) mapped through the corrections as the
update's step 0 maps it. A run without a log gives exactly what it gave before.

The scene: a tiny generated easy scene with RealSense-like depth (the contact rule runs there, so
the pre-contact labels differ from the run's at a few points), segmented once per module.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.annotations import Annotations, Delete, Merge, SetCategory, Split
from clutt3r_core.errors import SceneError
from tests.core.update._scenes import noisy_contact_run


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    run, seg, pre = noisy_contact_run(tmp_path_factory.mktemp("step0"), seed=0)
    cleared = (pre >= 0) & (seg.instance < 0)
    assert cleared.any(), "the contact rule cleared nothing: the merge test below would not tell the labels apart"
    return run, seg, pre


@pytest.fixture
def run(base, tmp_path):
    from tests.core.query._fake import copy_run

    return copy_run(base[0], base[0].parent, tmp_path / "run")  # run.json keeps the scene folder


def _edit(run, seg, *ops) -> None:
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        for op in ops:
            ann.apply_op(op)


def _roles(seg, pre) -> tuple[int, int, int]:
    """(into, merged, other): ``merged`` is an instance the contact rule cleared points of (so its
    grasp target tells the pre-contact labels from the run's), ``into`` the largest other one."""
    counts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
    b = int(np.bincount(pre[(pre >= 0) & (seg.instance < 0)]).argmax())
    rest = [int(k) for k in np.argsort(-counts) if k != b]
    return rest[0], b, rest[1]


def test_grasp_target_of_a_merged_id_is_the_union_of_both_pre_contact_instances(run, base):
    from clutt3r_core.grasping.request import request_from_run

    _, seg, pre = base
    a, b, _ = _roles(seg, pre)
    _edit(run, seg, Merge(into=a, other=b))
    req, _, _ = request_from_run(run, a)
    want = np.isin(pre, [a, b])
    np.testing.assert_array_equal(req.target, want)
    assert not np.array_equal(want, np.isin(seg.instance, [a, b]))  # the contact's points are in it
    with pytest.raises(SceneError, match=f"I{b} was merged into I{a} in the Edit tab .*entry 1.*I{a}'s"):
        request_from_run(run, b)


def test_a_deleted_id_is_refused_and_its_points_are_no_target(run, base):
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_core.update.run_labels import step_zero_labels

    _, seg, pre = base
    a, _, c = _roles(seg, pre)
    _edit(run, seg, SetCategory(a, "mug"), Delete(c))
    with pytest.raises(SceneError, match=f"I{c} was deleted in the Edit tab .*entry 2"):
        request_from_run(run, c)
    z = step_zero_labels(seg, run)
    assert c not in z.labels.ids and not (z.geometry == c).any() and z.corrected
    req, _, _ = request_from_run(run, a)  # an untouched instance keeps exactly its pre-contact target
    np.testing.assert_array_equal(req.target, pre == a)


def test_a_split_divides_the_pre_contact_points_between_its_parts(run, base):
    from clutt3r_core.grasping.request import request_from_run

    _, seg, pre = base
    _, b, _ = _roles(seg, pre)  # the instance with cleared contact points
    pts = np.flatnonzero(seg.instance == b)
    half = pts[seg.points[pts, 0] < np.median(seg.points[pts, 0])]
    _edit(run, seg, Split(points=tuple(half.tolist()), source=b))
    k = seg.num_instances  # the Edit tab's new id
    tk, tb = request_from_run(run, k)[0].target, request_from_run(run, b)[0].target
    assert not (tk & tb).any() and np.array_equal(tk | tb, pre == b)  # every pre-contact point, once
    assert tk[half].all() and not tb[half].any()


def test_without_corrections_the_request_is_what_it_was(run, base):
    from clutt3r_core.grasping.request import request_from_run, request_from_segmentation

    _, seg, pre = base
    for k in range(seg.num_instances):
        np.testing.assert_array_equal(request_from_run(run, k)[0].target, pre == k)
        np.testing.assert_array_equal(request_from_segmentation(seg, k).target, pre == k)
    with pytest.raises(SceneError, match="does not exist"):
        request_from_run(run, seg.num_instances)
    # a log whose edits are all undone: the run's own ids, the same requests
    a, b, _ = _roles(seg, pre)
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=a, other=b))
        ann.undo()
    for k in range(seg.num_instances):
        np.testing.assert_array_equal(request_from_run(run, k)[0].target, pre == k)


def test_gone_reasons_follow_a_merge_chain():
    from clutt3r_core.corrections import BaseLabels, apply
    from clutt3r_core.update.run_labels import gone_reasons

    inst = np.array([0, 0, 1, 1, 2, 2, 3, 3], np.int32)
    base = BaseLabels(inst, np.ones(4, np.float32), np.arange(8, dtype=np.int32))
    ops = (Merge(into=1, other=0), Merge(into=2, other=1), Delete(3))
    why = gone_reasons(ops, apply(base, ops))
    assert set(why) == {0, 1, 3}
    assert "I0 was merged into I1" in why[0] and "now part of I2" in why[0] and "entry 1" in why[0]
    assert "entry 3" in why[3] and "deleted" in why[3]


# -- the query ---------------------------------------------------------------------------------


def test_query_at_step_zero_ranks_the_corrected_ids(run, base):
    from clutt3r_core.query import RunQuery, target_points
    from tests.core.query._fake import FakeGrounder

    _, seg, pre = base
    a, b, c = _roles(seg, pre)
    before = RunQuery.open(run, grounder=FakeGrounder())
    r0 = before.query("red thing")
    assert before.labelling is None and before.scene is None and r0.scene == ""  # no log: as always
    _edit(run, seg, Merge(into=a, other=b), Delete(c))
    rq = RunQuery.open(run, grounder=FakeGrounder())
    r = rq.query("red thing")
    assert set(r.ranking) == {a} | (set(range(seg.num_instances)) - {a, b, c})
    assert b not in r.ranking and c not in r.ranking
    assert r.step == 0 and "with its corrections" in r.scene and "entry 2" in r.scene
    # the merged id's evidence mixes its parts by size (as after an update, corrected_evidence)
    na, nb = (int((seg.instance[: len(seg.points)] == k).sum()) for k in (a, b))
    assert 0 < na and 0 < nb
    e0, e = before.instances, rq.instances
    mix = (na * e0.colors[a] + nb * e0.colors[b]) / (na + nb)
    np.testing.assert_allclose(e.colors[a], mix, atol=0.02)  # rim voxels are left out of the share
    # the target's points: the corrected instance (what the Edit tab shows)
    pts, _ = target_points(rq.scene, a)
    assert len(pts) == int(np.isin(seg.instance, [a, b]).sum())
    # the update's re-embedding still reads the run's rows
    raw = RunQuery.open(run, grounder=FakeGrounder(), corrections=False)
    assert raw.labelling is None and raw.instances.num_instances == seg.num_instances


def test_query_without_corrections_is_identical(run, base):
    from clutt3r_core.query import RunQuery
    from tests.core.query._fake import FakeGrounder

    _, seg, pre = base
    a, b, _ = _roles(seg, pre)
    r0 = RunQuery.open(run, grounder=FakeGrounder(), corrections=False).query("green thing")
    with Annotations.open(run, segmentation=seg, author="test") as ann:  # a log that changes no label
        ann.apply_op(SetCategory(a, "mug"))
        ann.apply_op(Merge(into=a, other=b))
        ann.undo()
    for rq in (RunQuery.open(run, grounder=FakeGrounder()), RunQuery.open(run, grounder=FakeGrounder(), step=0)):
        r = rq.query("green thing")
        assert rq.labelling is None and r.ranking == r0.ranking and r.target == r0.target and r.scene == ""
        np.testing.assert_array_equal(r.scores, r0.scores)


# -- the commands ------------------------------------------------------------------------------


def test_grasp_command_refuses_a_merged_id_and_records_the_log(run, base, capsys):
    from clutt3r_core.cli import main

    _, seg, pre = base
    a, b, _ = _roles(seg, pre)
    main(["grasp", str(run), "--instance", str(a), "--json", "--top", "2"])
    plain = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert "corrections" not in plain and "corrections" not in json.loads((run / "grasps.json").read_text())
    _edit(run, seg, Merge(into=a, other=b))
    with pytest.raises(SystemExit, match=f"I{b} was merged into I{a}"):
        main(["grasp", str(run), "--instance", str(b)])
    capsys.readouterr()
    main(["grasp", str(run), "--instance", str(a), "--json", "--top", "2"])
    cap = capsys.readouterr()
    obj = json.loads(cap.out.strip().splitlines()[-1])
    assert obj["corrections"]["entries"] == 1 and obj["corrections"]["active_edits"] == 1
    assert json.loads((run / "grasps.json").read_text())["corrections"] == obj["corrections"]
    n = int(np.isin(pre, [a, b]).sum())
    assert f"({n} points)" in cap.err and "with its corrections" in cap.err


def test_query_command_json_names_the_log_and_skips_merged_ids(run, base, capsys):
    from clutt3r_core.commands.query import query_command
    from tests.core.query._fake import fake_ground_registered

    _, seg, pre = base
    a, b, _ = _roles(seg, pre)
    _edit(run, seg, Merge(into=a, other=b))
    with fake_ground_registered():
        query_command(run, "red thing", json=True, backend="fake-ground")
    obj = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    ids = [r["instance"] for r in obj["ranking"]]
    assert b not in ids and a in ids and obj["step"] == 0 and obj["corrections"]["entries"] == 1
    with np.load(run / "query_target.npz") as z:
        k = int(z["instance"])
        assert len(z["points"]) == int((np.where(seg.instance == b, a, seg.instance) == k).sum())


# -- the mapping, as a property ----------------------------------------------------------------

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402


@settings(max_examples=40, deadline=None)
@given(st.integers(2, 6), st.integers(0, 10_000), st.booleans(), st.integers(0, 20))
def test_merged_geometry_is_the_union_of_the_parts_pre_contact_points(k, seed, delete_one, rim):
    """For any labelling whose contact rule cleared some points (each instance keeps one), merging
    ids into another gives each id the pre-contact points of the ids now in it, and a deleted id
    none: ``corrected_geometry_labels`` is the pre-contact labels mapped through the edits, whatever
    the number of rim voxels (the last ``rim`` points; fused points are mapped among the fused ones)."""
    from types import SimpleNamespace

    from clutt3r_core.corrections import BaseLabels, apply
    from clutt3r_core.update.run_labels import corrected_geometry_labels

    rng = np.random.default_rng(seed)
    n = 80
    pre = rng.integers(-1, k, n).astype(np.int32)
    pre[:k] = np.arange(k)  # every id has points
    run = np.where((rng.random(n) < 0.35) & (np.arange(n) >= k), -1, pre).astype(np.int32)  # the contact's
    seg = SimpleNamespace(points=rng.random((n, 3)).astype(np.float32), instance=run,
                          trace=SimpleNamespace(surface=SimpleNamespace(rim=rim)))
    ids = rng.permutation(k)
    into, merged = int(ids[0]), tuple(int(x) for x in ids[1:1 + rng.integers(1, k)])
    ops = [Merge(into=into, other=merged[0], others=merged[1:])]
    rest = [int(x) for x in ids if int(x) != into and int(x) not in merged]
    gone = rest[0] if delete_one and rest else None
    if gone is not None:
        ops.append(Delete(gone))
    lab = apply(BaseLabels(run, np.ones(k, np.float32), np.arange(n, dtype=np.int32)), ops)
    geom = corrected_geometry_labels(seg, lab.instance, n, pre)
    lut = np.arange(k)
    lut[list(merged)] = into
    want = np.where(pre >= 0, lut[np.maximum(pre, 0)], -1)
    if gone is not None:
        want[pre == gone] = -1
    np.testing.assert_array_equal(geom, want)


def test_step_zero_of_an_updated_run_reads_the_corrections_now(run, base):
    """``--step 0`` on a run with updates: the Edit tab's ids as they are now (a delete made after
    the update, which makes the chain stale, is already in step 0), while the chain keeps its own."""
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_core.query import RunQuery
    from clutt3r_core.update.state import apply_update, save_state, state_from_run
    from tests.core.query._fake import FakeGrounder
    from tests.viewer.test_update_sources import _fake_update

    _, seg, pre = base
    a, b, c = _roles(seg, pre)
    _edit(run, seg, Merge(into=a, other=b))
    s0 = state_from_run(run)
    r1 = _fake_update(s0, 8, k=a, shift=0.05, removed=None, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    _edit(run, seg, Delete(c))  # after the update
    r0 = RunQuery.open(run, grounder=FakeGrounder(), step=0).query("red thing")
    assert b not in r0.ranking and c not in r0.ranking and a in r0.ranking and r0.step == 0
    with pytest.raises(SceneError, match=f"I{c} was deleted"):
        request_from_run(run, c, step=0)
    np.testing.assert_array_equal(request_from_run(run, a, step=0)[0].target, np.isin(pre, [a, b]))
    r1q = RunQuery.open(run, grounder=FakeGrounder(), step=1).query("red thing")
    assert c in r1q.ranking and b not in r1q.ranking  # the chain's labelling (stale: said by the commands)


def test_one_corrections_record_at_step_zero_and_after_updates():
    """``LabelSource.record`` is the "corrections" of grasps.json everywhere: None for the run as
    segmented, ``to_json`` with log entries (``StepZeroLabels.to_json`` and ``SceneAfter.corrections``
    both read it; review 11: they were two copies)."""
    from clutt3r_core.update.run_labels import LabelSource

    assert LabelSource(0, 0, "0" * 64).record() is None
    src = LabelSource(3, 2, "a" * 64, ((1, "mug"),))
    assert src.record() == src.to_json() and src.record()["categories"] == {"1": "mug"}
    assert LabelSource.from_json(src.record()) == src
