"""The demo loop after an update (issue 10): ``clutt3r query`` / ``clutt3r grasp`` on the scene after
the run's update chain (``update/scene_after.py``).

A tiny generated run gets a chain of two updates built through the core's API
(``apply_update`` / ``save_state``, as tests/viewer/_update_chain.py does):

1. frame F (a view the scene folder has): the orange instance is removed (grasped), instance D is
   pushed ``SHIFT_1`` along x, and a new instance K appears whose mask in view F is the orange
   object's mask (so the backend describes it as orange);
2. frame F: D is pushed ``SHIFT_2`` along y (motions compose).

The backend is ``tests/core/query/_fake.FakeGrounder`` (colour classes: wiring, not language).
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from clutt3r_core.commands.grasp import grasp_command
from clutt3r_core.commands.query import query_command
from clutt3r_core.errors import Clutt3rError, SceneError, SceneFileError
from clutt3r_core.language.colors import COLOR_WORDS, color_shares
from clutt3r_core.query import RunQuery
from clutt3r_core.runs import save_run
from clutt3r_core.synth import write_synth_scene
from clutt3r_core.update import InstanceUpdate, UpdateResult
from clutt3r_core.update.newobj import next_instance_id
from clutt3r_core.update.scene_after import compose_motions, scene_after
from clutt3r_core.update.state import apply_update, save_state, state_from_segmentation
from clutt3r_core.update.types import NewInstance, NewMask
from tests.core._tiny_run import tiny_scene, tiny_segmentation
from tests.core.query._fake import FakeGrounder, copy_run, fake_ground_registered

SHIFT_1 = np.array([0.06, 0.0, 0.0])
SHIFT_2 = np.array([0.0, 0.04, 0.0])
NEW_OFFSET = np.array([0.0, 0.0, 0.12])


def _T(t) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = t
    return T


def _result(frame, recs, added=(), new_masks=()) -> UpdateResult:
    return UpdateResult(frame, tuple(recs), tuple(new_masks), np.zeros((len(recs), 4, 4), bool),
                        np.full((4, 4), -1, np.int32), 0.1, added=tuple(added))


def _orange(seg) -> int:
    """The run instance with the largest orange share of its points' colours (the tiny scene's clamp)."""
    o = COLOR_WORDS.index("orange")
    cols = np.asarray(seg.colors)
    share = [color_shares(cols[seg.instance == k][None], np.ones((1, 1, int((seg.instance == k).sum())), bool))[0, o]
             for k in range(seg.num_instances)]
    return int(np.argmax(share))


@pytest.fixture(scope="module")
def chain(tmp_path_factory):
    root = tmp_path_factory.mktemp("sa")
    scene = tiny_scene()
    seg = tiny_segmentation()
    scene_dir = write_synth_scene(scene, root / "scene", contact_sheet=False)
    run = save_run(seg, root / "run", scene_root=scene_dir)
    removed = _orange(seg)
    moved = next(k for k in range(seg.num_instances) if k != removed)
    view = scene.initial_views[0]
    # the orange object's mask in that view: the added instance is described from it
    o = COLOR_WORDS.index("orange")
    mask = int(view.masks.ids[int(np.argmax(color_shares(view.rgb, view.masks.stack())[:, o]))])
    s0 = state_from_segmentation(seg, run=run)
    k = next_instance_id(s0)
    g = np.arange(13) * 0.0025
    a, b = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
    cube = np.unique(np.concatenate([np.stack(f, 1) for f in ((a, b, 0 * a), (a, b, 0 * a + g[-1]), (a, 0 * a, b),
                                                              (a, 0 * a + g[-1], b), (0 * a, a, b), (0 * a + g[-1], a, b))]),
                     axis=0)
    pts = (cube - cube.mean(0) + seg.points.mean(0) + NEW_OFFSET).astype(np.float32)
    emb = np.zeros(s0.embeddings.shape[1], np.float32)
    recs = [InstanceUpdate(int(i), "removed", None, None, None) if i == removed else
            InstanceUpdate(int(i), "displaced", 0.1, 0.9, _T(SHIFT_1)) if i == moved else
            InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s0.instance_ids]
    r1 = _result(view.frame, recs + [InstanceUpdate(k, "new", None, 0.9, None, mask, "new-depth")],
                 [NewInstance(k, mask, pts, np.tile(np.array([240, 120, 20], np.uint8), (len(pts), 1)), emb)],
                 (NewMask(mask, 100, k),))
    s1 = apply_update(s0, r1)
    save_state(s1, run / "updates" / f"01_frame_{view.frame:06d}", r1)
    r2 = _result(view.frame, [InstanceUpdate(int(i), "displaced", 0.1, 0.9, _T(SHIFT_2)) if i == moved else
                              InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s1.instance_ids])
    save_state(apply_update(s1, r2), run / "updates" / f"02_frame_{view.frame:06d}", r2)
    return root, run, seg, removed, moved, k


@pytest.fixture
def run_copy(chain, tmp_path):
    root, run, *_ = chain
    return copy_run(run, root, tmp_path / "run")


@pytest.fixture
def fake_registered():
    with fake_ground_registered():
        yield


def test_scene_after_leaves_out_moves_and_adds(chain):
    _, run, seg, removed, moved, k = chain
    sa = scene_after(run)
    assert sa.step == 2 and sa.n_updates == 2 and sa.label.startswith("scene after update 2 (frame ")
    assert not np.any(sa.instance == removed) and removed in sa.removed and sa.removed[removed][0] == 1
    assert set(sa.present.tolist()) == (set(range(seg.num_instances)) - {removed}) | {k}
    assert sa.added == {k: (1, sa.frame)} and sa.displaced == (moved,)
    old = np.asarray(seg.points, np.float64)[seg.instance == moved]
    np.testing.assert_allclose(sa.points_of(moved)[0], old + SHIFT_1 + SHIFT_2, atol=1e-5)
    # the normals of the moved points turned with them (a translation: unchanged), added ones unit
    np.testing.assert_allclose(sa.normals[sa.instance == moved], np.asarray(seg.normals)[seg.instance == moved],
                               atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(sa.normals[sa.instance == k], axis=1), 1.0, atol=1e-5)
    s1 = scene_after(run, 1)
    np.testing.assert_allclose(s1.points_of(moved)[0], old + SHIFT_1, atol=1e-5)
    s0 = scene_after(run, 0)
    np.testing.assert_array_equal(s0.points, np.asarray(seg.points, np.float32))
    assert s0.label == "the run as segmented" and not s0.removed


def test_removed_instance_is_one_clear_error(chain):
    _, run, _, removed, _, _ = chain
    with pytest.raises(SceneError, match=rf"instance {removed} was removed by update 1 \(frame \d+\)"):
        scene_after(run).check_present(removed)


@pytest.mark.parametrize("step", [-1, 3])
def test_bad_step_is_one_clear_error(run_copy, fake_registered, step):
    with pytest.raises(Clutt3rError, match=rf"--step {step} does not exist: the run has 2 update\(s\)"):
        query_command(run_copy, "orange", backend="fake-ground", step=step)
    with pytest.raises(Clutt3rError, match=rf"--step {step} does not exist"):
        grasp_command(run_copy, instance=0, step=step)


def test_query_after_update_ranks_the_added_not_the_removed(run_copy, chain, fake_registered, capsys):
    _, _, seg, removed, _, k = chain
    before = RunQuery.open(run_copy, grounder=FakeGrounder(), step=0).query("orange")
    assert before.target == removed and before.step == 0  # the orange object, as segmented
    query_command(run_copy, "orange", json=True, backend="fake-ground")
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert d["step"] == 2 and d["scene"].startswith("scene after update 2")
    ids = [r["instance"] for r in d["ranking"]]
    assert removed not in ids and k in ids and sorted(ids) == sorted(set(range(seg.num_instances)) - {removed} | {k})
    assert d["target"] == k  # described from the orange object's mask in the post view
    with np.load(run_copy / "query_target.npz") as z:
        assert int(z["instance"]) == k and int(z["step"]) == 2
        np.testing.assert_allclose(z["points"].mean(0), seg.points.mean(0) + NEW_OFFSET, atol=1e-3)
    query_command(run_copy, "orange", backend="fake-ground")
    out = capsys.readouterr().out
    assert "scene after update 2" in out and f"removed, not ranked: {removed} (update 1)" in out


def test_grasp_of_the_displaced_object_is_at_its_new_pose(run_copy, chain, capsys):
    _, _, seg, _, moved, _ = chain
    grasp_command(run_copy, instance=moved, json=True, top=5)
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert d["step"] == 2 and d["target"] == moved and d["grasps"]
    new = np.asarray(seg.points, np.float64)[seg.instance == moved] + SHIFT_1 + SHIFT_2
    lo, hi = new.min(0) - 0.01, new.max(0) + 0.01
    for g in d["grasps"]:
        c = np.asarray(g["T_world_gripper"])[:3, 3]
        assert np.all((c >= lo) & (c <= hi)), (c, lo, hi)  # on the object where it is now
        if "contacts" in g:  # both jaws touch the moved points (within 1 cm)
            for p in np.asarray(g["contacts"]).reshape(-1, 3):
                assert np.min(np.linalg.norm(new - p, axis=1)) < 0.01
    # the same grasps at step 0 are where the object was
    grasp_command(run_copy, instance=moved, json=True, top=5, step=0)
    d0 = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    c0 = np.mean([np.asarray(g["T_world_gripper"])[:3, 3] for g in d0["grasps"]], axis=0)
    c2 = np.mean([np.asarray(g["T_world_gripper"])[:3, 3] for g in d["grasps"]], axis=0)
    assert d0["step"] == 0
    np.testing.assert_allclose(c2 - c0, SHIFT_1 + SHIFT_2, atol=0.01)


def test_grasp_of_removed_and_added(run_copy, chain, capsys):
    _, _, _, removed, _, k = chain
    with pytest.raises(SceneError, match=f"instance {removed} was removed by update 1"):
        grasp_command(run_copy, instance=removed)
    grasp_command(run_copy, instance=k, json=True, top=3)
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert d["target"] == k and d["grasps"]  # the added 3 cm cube is graspable
    c = np.asarray(d["grasps"][0]["T_world_gripper"])[:3, 3]
    assert np.linalg.norm(c - (tiny_segmentation().points.mean(0) + NEW_OFFSET)) < 0.02


@settings(max_examples=25, deadline=None)
@given(st.lists(st.lists(st.tuples(st.integers(0, 3), st.floats(-0.2, 0.2)), max_size=3, unique_by=lambda t: t[0]),
                max_size=4))
def test_compose_motions_is_the_product_of_each_instance_motions(steps):
    # an update names each instance once (one status each)
    Ts = [[(k, _T([x, 2 * x, -x]) @ _rot(x)) for k, x in s] for s in steps]
    M = compose_motions(Ts, 4)
    assert M.shape == (len(steps) + 1, 4, 4, 4)
    for k in range(4):
        want = np.eye(4)
        for u, s in enumerate(Ts):
            for kk, T in s:
                if kk == k:
                    want = T @ want
            np.testing.assert_allclose(M[u + 1, k], want, atol=1e-12)


def _rot(a: float) -> np.ndarray:
    T = np.eye(4)
    c, s = np.cos(a), np.sin(a)
    T[:2, :2] = [[c, -s], [s, c]]
    return T


def test_run_without_updates_is_queried_as_before(run_copy, fake_registered, capsys):
    shutil.rmtree(run_copy / "updates")
    query_command(run_copy, "orange", json=True, backend="fake-ground", step=0)  # --step 0 is always valid
    d = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert set(d) == {"query", "ranking", "target", "confident", "time_s"}  # no step/scene keys: as before
    with np.load(run_copy / "query_target.npz") as z:
        assert "step" not in z.files
    with pytest.raises(Clutt3rError, match=r"--step 1 does not exist: the run has 0 update\(s\)"):
        RunQuery.open(run_copy, grounder=FakeGrounder(), step=1)
    grasp_command(run_copy, instance=0, json=True, top=1)
    assert "step" not in json.loads(capsys.readouterr().out.strip().splitlines()[-1])


def test_python_grasp_request_is_the_commands(chain):
    from clutt3r_core.grasping.request import request_from_run

    _, run, seg, removed, moved, _ = chain
    req, _, note = request_from_run(run, moved)
    assert note.startswith("scene after update 2") and req.views == ()
    np.testing.assert_allclose(req.points[req.target].mean(0),
                               np.asarray(seg.points, np.float64)[seg.instance == moved].mean(0) + SHIFT_1 + SHIFT_2,
                               atol=1e-5)
    req0, _, _ = request_from_run(run, moved, step=0)
    np.testing.assert_array_equal(req0.points, seg.points)
    with pytest.raises(SceneError, match=f"instance {removed} was removed by update 1"):
        request_from_run(run, removed)


def test_the_post_cameras_are_read_from_update_json_and_older_files_still_work(run_copy, chain, monkeypatch):
    """An update records its post view's camera in update.json ("camera"); ``grasping.request.scene_now``
    orients the added instance's normals from it without loading the scene folder. update.json
    files written before (no "camera") still get the scene folder's view of the frame: the same
    normals."""
    import clutt3r_core.io
    from clutt3r_core.grasping.request import scene_now
    from clutt3r_core.scene import Camera
    from clutt3r_core.update.scene_after import post_cameras
    from clutt3r_core.update.update import update_scene
    from tests.core.update.test_update import FAST

    _, _, seg, _, _, k = chain
    view = tiny_scene().initial_views[0]
    # the writer: an update made now carries its view's camera, exactly (JSON floats round-trip)
    res = update_scene(state_from_segmentation(seg), view, FAST)
    folder = save_state(state_from_segmentation(seg), run_copy.parent / "fresh", res)
    cam = Camera.from_json(json.loads((folder / "update.json").read_text())["camera"])
    for x in ("K", "T_world_camera"):
        np.testing.assert_array_equal(getattr(cam, x), getattr(view.camera, x))
    assert (cam.width, cam.height) == (view.camera.width, view.camera.height)

    # the reader, on update.json files written before: no camera recorded, the scene folder's view
    assert post_cameras(run_copy, 2) == {}
    old = scene_now(run_copy, 2)
    plus_z = scene_after(run_copy, 2)  # no eyes at all: +z
    sel = old.instance == k
    assert not np.array_equal(old.normals[sel], plus_z.normals[sel])  # the camera matters to the test

    # ... and on files that record it: the scene folder is not read, the same normals
    for d in sorted((run_copy / "updates").iterdir()):
        doc = json.loads((d / "update.json").read_text())
        (d / "update.json").write_text(json.dumps({**doc, "camera": view.camera.to_json()}))

    def no_scene(*a, **kw):
        raise AssertionError("the scene folder was loaded")

    monkeypatch.setattr(clutt3r_core.io, "load_scene", no_scene)
    assert set(post_cameras(run_copy, 2)) == {view.frame}
    new = scene_now(run_copy, 2)
    np.testing.assert_array_equal(new.normals, old.normals)
    np.testing.assert_array_equal(new.points, old.points)

    # a damaged record: one error naming the file
    d = sorted((run_copy / "updates").iterdir())[0]
    doc = json.loads((d / "update.json").read_text())
    (d / "update.json").write_text(json.dumps({**doc, "camera": {"K": [[1, 0, 0]]}}))
    with pytest.raises(SceneFileError, match=r"update\.json.*invalid \"camera\""):
        post_cameras(run_copy, 2)
