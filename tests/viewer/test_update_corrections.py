"""The viewer's update chain with corrections (session 7): the chain's ids are the corrected ids it
was computed from, and the Updates tab says when the Edit tab's labels changed since."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np

from clutt3r_core.annotations import Annotations, Delete, Merge
from clutt3r_core.update.state import apply_update, save_state, state_from_run

from .test_update_sources import _fake_update


def _two(seg) -> tuple[int, int, int]:
    counts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
    a, b, c = (int(k) for k in np.argsort(-counts)[:3])
    return a, b, c


def test_updates_tab_follows_the_corrected_chain_and_flags_later_edits(tiny_run_dir, tiny_seg, tmp_path):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.panels.update_sources import stale_text
    from clutt3r_viewer.panels.updates import UpdatesPanel
    from clutt3r_viewer.scene_step import shown_scene

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    a, b, c = _two(tiny_seg)
    ann = Annotations.open(run, segmentation=tiny_seg, author="test")
    ann.apply_op(Merge(into=a, other=b))
    s0 = state_from_run(run)  # the corrected labelling: b's points are a's
    r1 = _fake_update(s0, 8, k=a, shift=0.05, removed=None, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)

    d = load_viewer_data(run, images=False)
    np.testing.assert_array_equal(d.updates[0].instance0, ann.current.instance)
    idx = np.arange(len(tiny_seg.points))
    was_b = tiny_seg.instance == b
    sc = shown_scene(d, 1, idx)  # after update 1
    inst, gone = sc.instance, sc.gone
    assert np.all(inst[was_b] == a) and not gone.any()
    pts = sc.points  # the merged fragment moves with the instance it joined
    np.testing.assert_allclose(pts[was_b, 0] - tiny_seg.points[was_b, 0], 0.05, atol=1e-5)

    app = SimpleNamespace(data=d, instance_labels=lambda: ann.current.instance)
    session = SimpleNamespace(app=app, scene_step=lambda: 1)
    assert stale_text(d, ann.current.instance) is None
    assert "Stale" not in UpdatesPanel()._timeline(session)

    ann.apply_op(Delete(c))  # an edit after the update
    note = stale_text(d, ann.current.instance)
    assert note is not None and "\n" not in note and f"no longer instances: I{c}" in note and "--recompute" in note
    md = UpdatesPanel()._timeline(session)
    assert md.startswith(f"**⚠ {note}**") and "1 · frame 8" in md
    ann.undo()
    assert stale_text(d, ann.current.instance) is None  # back to the chain's labels
    ann.close()


def test_a_run_whose_update_chain_cannot_be_read_opens_without_it_and_says_why(tiny_run_dir, tiny_seg, tmp_path):
    """The correction log a corrected chain was computed from is gone (or an update.json is
    broken): the viewer still opens the run, without its updates, with one ``updates-unreadable``
    run warning naming the file; nothing on disk is changed (the user's updates stay)."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.panels.warnings import warnings_markdown

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    a, b, _ = _two(tiny_seg)
    with Annotations.open(run, segmentation=tiny_seg, author="test") as ann:
        ann.apply_op(Merge(into=a, other=b))
    s0 = state_from_run(run)
    r1 = _fake_update(s0, 8, k=a, shift=0.05, removed=None, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    assert len(load_viewer_data(run, images=False).updates) == 1

    before = sorted(p.relative_to(run) for p in (run / "updates").rglob("*"))
    shutil.move(run / "corrections", tmp_path / "corrections")  # the chain's labelling cannot be rebuilt
    d = load_viewer_data(run, images=False)
    assert d.updates == ()
    w = [x for x in d.seg.warnings if x.code == "updates-unreadable"]
    assert len(w) == 1 and "ops.jsonl" in w[0].message and "shown without its updates" in w[0].message
    assert "updates-unreadable" in warnings_markdown(d.seg.warnings)
    assert sorted(p.relative_to(run) for p in (run / "updates").rglob("*")) == before  # nothing removed

    shutil.move(tmp_path / "corrections", run / "corrections")
    (run / "updates" / "01_frame_000008" / "update.json").write_text("{ not json")
    d = load_viewer_data(run, images=False)
    assert d.updates == () and any("update.json" in x.message for x in d.seg.warnings)


def test_removed_instances_of_a_corrected_chain_are_ghosted_in_the_corrected_ids_colours(tiny_run_dir, tiny_seg,
                                                                                        tmp_path):
    """A merge (b into a) before the update, then the update removes a: every ghost, b's former
    points included, is drawn pale in a's colour (the id the chain removed), not in b's (the run's
    id), in the "update" layer and in every other layer (``ghost_removed``)."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_viewer.data import label_colors
    from clutt3r_viewer.layers import GHOST_WHITE, LayerInput, ghost_removed
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.panels.update_sources import UpdateSceneLayer
    from clutt3r_viewer.scene_step import shown_scene
    from clutt3r_viewer.state import SessionState

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    a, b, c = _two(tiny_seg)
    with Annotations.open(run, segmentation=tiny_seg, author="test") as ann:
        ann.apply_op(Merge(into=a, other=b))
        labels = ann.current.instance
    s0 = state_from_run(run)
    r1 = _fake_update(s0, 8, k=c, shift=0.05, removed=a, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    d = load_viewer_data(run, images=False)

    idx = np.arange(len(tiny_seg.points))
    was_a, was_b = tiny_seg.instance == a, tiny_seg.instance == b
    pale = lambda k: np.round((1 - GHOST_WHITE) * label_colors(np.array([k])).astype(np.float32)  # noqa: E731
                              + GHOST_WHITE * 255).astype(np.uint8)[0]
    assert not np.array_equal(pale(a), pale(b))  # the test tells the two apart
    sc = shown_scene(d, 1, idx)
    np.testing.assert_array_equal(sc.gone, was_a | was_b)
    assert np.all(sc.last_instance[was_b] == a) and np.all(sc.instance[was_b] == -1)

    state = SessionState()
    state.update, state.update_after = 0, True
    inp = LayerInput(data=d, idx=idx, instance=labels, scores=np.ones(tiny_seg.num_instances + 1, np.float32))
    col = UpdateSceneLayer().colors(inp, state)
    assert np.all(col[was_b] == pale(a)) and np.all(col[was_a] == pale(a))
    col = ghost_removed(label_colors(sc.instance), sc)  # any other layer's colours, ghosted
    assert np.all(col[was_b] == pale(a)) and np.all(col[~sc.gone] == label_colors(sc.instance)[~sc.gone])
