"""User corrections carried into scene updates (session 7, ``update/run_labels.py``).

A tiny generated run (``tests/core/_tiny_run``) is corrected through the correction log's API (what
the viewer's Edit tab calls), then updated through ``clutt3r update RUN --image ...`` with one of the
scene's own views as the post-interaction image (nothing moved): the update's ids must be the
corrected ids, a correction made after an update must make the chain stale (refused, with the way
out), and a run without corrections must give exactly what it gave before.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from clutt3r_core.annotations import Annotations, Delete, Merge, SetCategory, Split
from clutt3r_core.commands.update import update_command
from clutt3r_core.errors import Clutt3rError
from clutt3r_core.io.images import write_png
from clutt3r_core.runs import save_run
from clutt3r_core.update.run_labels import run_labels, stale_note
from clutt3r_core.update.scene_after import scene_after
from clutt3r_core.update.state import latest_state, save_state, state_from_run, state_from_segmentation
from clutt3r_core.update.update import update_scene
from tests.core._tiny_run import tiny_scene, tiny_segmentation

from .test_update import FAST


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    root = tmp_path_factory.mktemp("corr")
    seg, scene = tiny_segmentation(), tiny_scene()
    run = save_run(seg, root / "run")
    view = scene.initial_views[0]  # the post-interaction image: the scene unchanged
    img = root / "post"
    (img / "masks").mkdir(parents=True)
    write_png(img / "post.png", view.rgb)
    for m, i in zip(view.masks.masks, view.masks.ids):
        write_png(img / "masks" / f"mask_000008_{i:02d}.png", m.astype(np.uint8) * 255)
    cam = view.camera
    (img / "cam.json").write_text(json.dumps({"K": cam.K.tolist(), "width": cam.width, "height": cam.height,
                                              "T_world_camera": cam.T_world_camera.tolist()}))
    return run, seg, view, img


@pytest.fixture
def run(base, tmp_path):
    dst = tmp_path / "run"
    shutil.copytree(base[0], dst)
    return dst


def _largest(seg, n: int) -> list[int]:
    counts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
    return [int(k) for k in np.argsort(-counts)[:n]]


def _edit(run, seg, *ops) -> None:
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        for op in ops:
            ann.apply_op(op)


def _update(run, img, **kw) -> dict:
    update_command(run, image=img / "post.png", masks=img / "masks", camera=img / "cam.json", config=FAST,
                   overlay=False, **kw)
    _, folder = latest_state(run)
    return json.loads((folder / "update.json").read_text())


def _ids(doc) -> list[int]:
    return [d["instance"] for d in doc["instances"]]


def test_merge_before_the_update_reports_one_instance(run, base):
    _, seg, _, img = base
    a, b = _largest(seg, 2)
    _edit(run, seg, Merge(into=a, other=b), SetCategory(a, "mug"))
    st = state_from_run(run)
    assert b not in st.instance_ids and a in st.instance_ids
    assert st.labels.entries == 2 and st.labels.active_edits == 2 and dict(st.labels.categories) == {a: "mug"}
    n_ab = int(np.isin(seg.instance[: len(st.points)], [a, b]).sum())
    assert int((st.instance == a).sum()) == n_ab  # both fragments' points, one id
    assert abs(float(np.linalg.norm(st.embedding_of(a))) - 1.0) < 1e-5
    doc = _update(run, img)
    ids = _ids(doc)
    assert ids.count(a) == 1 and b not in ids and sorted(ids) == st.instance_ids.tolist()
    assert doc["corrections"]["entries"] == 2 and doc["corrections"]["categories"] == {str(a): "mug"}
    assert stale_note(run) is None  # computed from the current corrections


def test_deleted_instance_is_never_reported(run, base):
    _, seg, _, img = base
    c = _largest(seg, 3)[2]
    _edit(run, seg, Delete(c))
    st = state_from_run(run)
    assert c not in st.instance_ids
    n = len(st.points)
    assert int((st.instance == -1).sum()) == int((seg.instance[:n] == -1).sum() + (seg.instance[:n] == c).sum())
    doc = _update(run, img)
    assert c not in _ids(doc)
    assert c not in scene_after(run, seg=seg).present


def test_split_instance_gets_the_edit_tabs_id(run, base):
    _, seg, _, _ = base
    a = _largest(seg, 1)[0]
    pts = np.flatnonzero(seg.instance == a)
    half = pts[seg.points[pts, 0] < np.median(seg.points[pts, 0])]
    _edit(run, seg, Split(points=tuple(half.tolist()), source=a))
    lab = run_labels(run, seg)
    k = seg.num_instances  # the Edit tab's new id: the number of ids so far
    assert lab.num_ids == k + 1 and k in lab.ids
    st = state_from_run(run)
    assert k in st.instance_ids and a in st.instance_ids
    # a split-off part inherits its source's embedding
    np.testing.assert_allclose(st.embedding_of(k), st.embedding_of(a), atol=1e-6)


def test_correction_after_an_update_is_flagged_stale(run, base):
    _, seg, _, img = base
    a, b = _largest(seg, 2)
    doc0 = _update(run, img)
    assert "corrections" not in doc0 and stale_note(run) is None
    _edit(run, seg, Merge(into=a, other=b))
    note = stale_note(run)
    assert note is not None and "\n" not in note
    assert note.startswith("STALE") and f"no longer instances: I{b}" in note and "--recompute" in note
    assert "the run as segmented" in note and "correction log entry 1" in note
    assert "--frame F --recompute" in note and "--frame 8 --recompute" in stale_note(run, frame=8)
    assert scene_after(run, seg=seg).stale == note  # query / grasp print it
    with pytest.raises(Clutt3rError, match="STALE"):
        _update(run, img)
    before = sorted(p.name for p in (run / "updates").iterdir())
    doc = _update(run, img, recompute=True)
    aside = [p for p in run.iterdir() if p.name.startswith("updates.stale-")]
    assert len(aside) == 1 and sorted(p.name for p in aside[0].iterdir()) == before  # kept, not deleted
    assert b not in _ids(doc) and doc["corrections"]["entries"] == 1 and stale_note(run) is None


def test_edit_then_undo_keeps_the_chain_current(run, base):
    _, seg, _, img = base
    a, b = _largest(seg, 2)
    _update(run, img)
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=a, other=b))
        ann.undo()
    assert stale_note(run) is None  # the labels are the ones the chain was computed from


def test_state_chain_replays_the_log_it_was_computed_from(run, base):
    """A chain computed after 1 correction, then more corrections: scene_after still uses the
    labelling of entry 1 (the chain's ids), and says it is stale."""
    _, seg, _, img = base
    a, b, c = _largest(seg, 3)
    _edit(run, seg, Merge(into=a, other=b))
    _update(run, img)
    sa = scene_after(run, seg=seg)
    assert sa.stale is None and b not in sa.present and c in sa.present
    _edit(run, seg, Delete(c))
    sa = scene_after(run, seg=seg)
    assert c in sa.present and sa.stale is not None and f"I{c}" in sa.stale


def test_run_without_corrections_updates_exactly_as_before(run, base):
    _, seg, view, img = base
    st_new = state_from_run(run)
    st_old = state_from_segmentation(seg, voxel_size=st_new.voxel_size, run=run)
    for name in ("points", "colors", "instance", "instance_ids", "embeddings"):
        np.testing.assert_array_equal(getattr(st_new, name), getattr(st_old, name))
    assert st_new.labels.entries == 0 and st_old.labels is None
    doc = _update(run, img)
    res = update_scene(st_old, view.__class__(-1, view.rgb, view.camera, None, view.masks, name="post.png"), FAST)
    old = save_state(st_old, run.parent / "old", res)
    doc_old = json.loads((old / "update.json").read_text())
    for d in (doc, doc_old):
        d.pop("time_s")
    assert doc == doc_old


def test_query_on_a_corrected_chain_ranks_the_corrected_ids(tmp_path):
    """A split before the update: the split-off id (not a run instance) is ranked with the
    evidence of the run instance it came from; the merged-away id is not ranked."""
    from clutt3r_core.query import RunQuery
    from clutt3r_core.synth import write_synth_scene
    from tests.core.query._fake import FakeGrounder, fake_ground_registered

    seg, scene = tiny_segmentation(), tiny_scene()
    run = save_run(seg, tmp_path / "run", scene_root=write_synth_scene(scene, tmp_path / "scene", contact_sheet=False))
    a, b, c = _largest(seg, 3)
    pts = np.flatnonzero(seg.instance == a)
    half = pts[seg.points[pts, 0] < np.median(seg.points[pts, 0])]
    _edit(run, seg, Split(points=tuple(half.tolist()), source=a), Merge(into=c, other=b))
    k = seg.num_instances
    st = state_from_run(run)
    res = update_scene(st, scene.initial_views[0], FAST)
    from clutt3r_core.update.state import apply_update

    s1 = apply_update(st, res)
    save_state(s1, run / "updates" / "01_frame_000000", res)
    # a second update adds an instance (described from a mask of the scene's view 0) on top of the corrected ids
    from clutt3r_core.update import InstanceUpdate, UpdateResult
    from clutt3r_core.update.newobj import next_instance_id
    from clutt3r_core.update.types import NewInstance, NewMask

    view = scene.initial_views[0]
    new = next_instance_id(s1)
    m = int(view.masks.ids[0])
    cube = (np.random.default_rng(0).random((200, 3)) * 0.02 + seg.points.mean(0) + [0, 0, 0.12]).astype(np.float32)
    recs = [InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s1.instance_ids]
    r2 = UpdateResult(view.frame, tuple(recs + [InstanceUpdate(new, "new", None, 0.9, None, m, "new-depth")]),
                      (NewMask(m, 100, new),), np.zeros((len(recs) + 1, 4, 4), bool), np.full((4, 4), -1, np.int32),
                      0.1, added=(NewInstance(new, m, cube, np.full((200, 3), 200, np.uint8), None),))
    save_state(apply_update(s1, r2), run / "updates" / "02_frame_000000", r2)
    with fake_ground_registered():
        rq = RunQuery.open(run, backend="fake-ground")
        r = rq.query("orange")
    assert new in rq.described and new > k
    assert sorted(r.ranking) == sorted(st.instance_ids.tolist() + [new]) and k in r.ranking and b not in r.ranking
    e = rq.instances
    np.testing.assert_allclose(e.colors[k], e.colors[a], atol=1e-6)  # the split part: its source's
    assert rq.scene.stale is None
    # re-embedding the corrected state with another backend (clutt3r update --embedder): rows by point share
    from clutt3r_core.update.embed import with_embedder

    st2 = with_embedder(st, "fake-ground", embedder=FakeGrounder())
    assert st2.instance_ids.tolist() == st.instance_ids.tolist()
    np.testing.assert_allclose(st2.embedding_of(k), st2.embedding_of(a), atol=1e-6)


def test_one_share_over_the_fused_points_for_the_state_the_query_and_the_embedder(tmp_path):
    """A run whose last points are rim voxels (``trace.surface.rim``) with a merge: the stored
    embedding of the merged id (the update's state), the query's ``SceneAfter.run_share`` and a
    re-embedding with ``--embedder`` mix the run instances by one share, counted over the fused
    points only (``run_labels.run_share``), which differs here from the whole cloud's."""
    from dataclasses import replace

    from clutt3r_core.update.embed import with_embedder
    from clutt3r_core.update.run_labels import fused_count, run_share
    from clutt3r_core.update.state import apply_update

    seg0 = tiny_segmentation()
    a, b = _largest(seg0, 2)
    # the rim: 60 % of a's points and 5 % of b's moved to the end of the cloud
    ia, ib = np.flatnonzero(seg0.instance == a), np.flatnonzero(seg0.instance == b)
    rim = np.concatenate([ia[: len(ia) * 6 // 10], ib[: len(ib) // 20]])
    order = np.concatenate([np.setdiff1d(np.arange(len(seg0.points)), rim), rim])
    seg = replace(seg0, points=seg0.points[order], colors=seg0.colors[order], normals=seg0.normals[order],
                  instance=seg0.instance[order], counts=seg0.counts[order],
                  trace=replace(seg0.trace, surface=replace(seg0.trace.surface, rim=len(rim))))
    assert fused_count(seg) == len(seg.points) - len(rim)
    run = save_run(seg, tmp_path / "run")
    _edit(run, seg, Merge(into=a, other=b))
    lab = run_labels(run, seg)
    share = run_share(lab.instance, seg, lab.num_ids)
    whole = np.zeros_like(share)
    both = (lab.instance >= 0) & (seg.instance >= 0)
    np.add.at(whole, (lab.instance[both], seg.instance[both]), 1.0)
    whole /= np.maximum(whole.sum(axis=1, keepdims=True), 1)
    assert abs(share[a, b] - whole[a, b]) > 1e-3  # the rim makes a difference here

    st = state_from_run(run)
    emb = state_from_segmentation(seg).embeddings  # the run instances' unit embeddings
    want = share[st.instance_ids] @ emb.astype(np.float64)
    want /= np.linalg.norm(want, axis=1, keepdims=True)
    np.testing.assert_allclose(st.embeddings, want, atol=1e-6)
    res = update_scene(st, tiny_scene().initial_views[0], FAST)
    save_state(apply_update(st, res), run / "updates" / "01_frame_000008", res)
    np.testing.assert_array_equal(scene_after(run, seg=seg).run_share, share)  # the query's share

    class Rows:  # a re-embedding with another embedder: rows = the run instances' (unit axes)
        name = "rows"

    import clutt3r_core.update.embed as embed_mod

    rows = np.eye(seg.num_instances, dtype=np.float32)
    orig = embed_mod.run_instance_embeddings
    embed_mod.run_instance_embeddings = lambda run_dir, emb_obj, scene=None: rows
    try:
        re = with_embedder(st, "rows", embedder=Rows())
    finally:
        embed_mod.run_instance_embeddings = orig
    mixed = share[st.instance_ids] / np.linalg.norm(share[st.instance_ids], axis=1, keepdims=True)
    np.testing.assert_allclose(re.embeddings, mixed, atol=1e-6)
