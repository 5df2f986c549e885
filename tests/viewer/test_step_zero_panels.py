"""The Grasps and Query tabs at step 0 follow the Edit tab's live edits (session 9,
``scene_step.step_zero_of``): after a merge the merged id is no target and is not ranked, the id it
joined is planned on both instances' points before the contact rule, and an undo brings the old ids
back (no stale cache). Driven without a browser against a real viser server; the edits go through the
run's ``Annotations`` as ``ViewerApp.edit_run`` applies them."""

from __future__ import annotations

import shutil
import threading
from types import SimpleNamespace

import numpy as np
import pytest

import clutt3r_core.query as cq
import clutt3r_viewer.panels.query as qp
from clutt3r_core.annotations import Annotations, Merge
from clutt3r_viewer.edit import option_id
from clutt3r_viewer.panels.grasps import GraspsPanel
from clutt3r_viewer.state import SessionState
from tests.core.query._fake import FakeGrounder
from tests.viewer.conftest import free_port


@pytest.fixture
def ann(tiny_run_dir, tiny_seg, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    a = Annotations.open(run, segmentation=tiny_seg, author="test")
    yield a
    a.close()


def _pair(seg) -> tuple[int, int]:
    counts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
    a, b = (int(k) for k in np.argsort(-counts)[-2:])  # the two smallest: the hand can hold them
    return a, b


def test_grasps_tab_plans_the_merged_instance_and_refuses_the_merged_id(tiny_data, ann):
    import viser

    from clutt3r_core.segmentation.refine import run_labels_before_contact

    seg = tiny_data.seg
    a, b = _pair(seg)
    pre = run_labels_before_contact(seg)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    notes = []
    try:
        s = SimpleNamespace(client=server, lock=threading.RLock(), state=SessionState(),
                            app=SimpleNamespace(data=tiny_data, annotations=ann),
                            notify=lambda title, body: notes.append(body), scene_step=lambda: 0)
        from clutt3r_viewer.panels.base import Change

        p = GraspsPanel()
        p.build(s)
        assert b in {option_id(o) for o in p.target.options}
        p.plan_for(s, a)
        assert f"({int((pre == a).sum())} target points)" in p.summary.content
        ann.apply_op(Merge(into=a, other=b))  # the Edit tab's merge (ViewerApp.edit_run applies it so)
        p.refresh(s, Change.LABELS)
        assert b not in {option_id(o) for o in p.target.options} and a in {option_id(o) for o in p.target.options}
        p.plan_for(s, a)
        n = int(np.isin(pre, [a, b]).sum())
        assert f"({n} target points)" in p.summary.content, p.summary.content
        p.plan_for(s, b)
        assert f"I{b} was merged into I{a}" in notes[-1]
        p._export(s)
        import json

        assert json.loads((ann.run_dir / "grasps.json").read_text())["corrections"]["entries"] == 1
        ann.undo()  # back: b is a target again (the cache follows the labels)
        p.refresh(s, Change.LABELS)
        assert b in {option_id(o) for o in p.target.options}
        p.plan_for(s, b)
        assert f"({int((pre == b).sum())} target points)" in p.summary.content
    finally:
        server.stop()


def test_query_tab_ranks_the_edit_tabs_ids_at_step_zero(tiny_data, ann, monkeypatch):
    monkeypatch.setattr(qp, "language_backend_name", lambda: "fake-ground")
    monkeypatch.setattr(cq, "create_grounder", lambda name=None: FakeGrounder())
    seg = tiny_data.seg
    a, b = _pair(seg)
    state = SimpleNamespace(query="", query_best=-1, query_scores=None, color_mode="instance")
    s = SimpleNamespace(app=SimpleNamespace(text_embedder=None, data=tiny_data, annotations=ann),
                        lock=threading.Lock(), state=state, changed=lambda c: None, scene_step=lambda: 0)
    panel = qp.QueryPanel()
    panel.result = SimpleNamespace(content="")
    panel.run_query(s, "the red thing")
    before = state.query_scores.copy()
    assert np.isfinite(before[[a, b]]).all()
    ann.apply_op(Merge(into=a, other=b))
    panel.run_query(s, "the red thing")
    after = state.query_scores
    assert np.isnan(after[b]) and np.isfinite(after[a]) and f"| I{b} |" not in panel.result.content
    assert "with its corrections" in panel.result.content or f"I{a}" in panel.result.content
    untouched = [k for k in range(seg.num_instances) if k not in (a, b)]
    assert np.isfinite(after[untouched]).all()
    ann.undo()
    panel.run_query(s, "the red thing")
    np.testing.assert_allclose(state.query_scores, before)  # the run's own ids again, same scores


def test_the_run_embedders_scores_follow_the_edits_and_the_corrected_chain(tiny_data, tiny_seg, ann, tmp_path):
    """The shared-space path (the run's own text embedder): per-run-instance cosines are carried to the
    Edit tab's ids at step 0 and to a corrected chain's ids after an update (a split-off id is ranked
    there; before, it had no score), each id mixing its parts' by size."""
    from clutt3r_core.annotations import Split
    from clutt3r_core.update.run_labels import run_share
    from clutt3r_core.update.state import apply_update, save_state, state_from_run
    from clutt3r_viewer.loading import load_viewer_data
    from tests.viewer.conftest import FakeTextEmbedder
    from tests.viewer.test_update_sources import _fake_update

    seg = tiny_seg
    a, b = _pair(seg)
    step = {"now": 0}
    state = SimpleNamespace(query="", query_best=-1, query_scores=None, color_mode="instance")
    s = SimpleNamespace(app=SimpleNamespace(text_embedder=FakeTextEmbedder(), data=tiny_data, annotations=ann),
                        lock=threading.Lock(), state=state, changed=lambda c: None, scene_step=lambda: step["now"])
    panel = qp.QueryPanel()
    panel.result = SimpleNamespace(content="")
    raw = tiny_data.instance_text_scores(FakeTextEmbedder().embed_text(["red"])[0])
    ann.apply_op(Merge(into=a, other=b))
    panel.run_query(s, "red")
    share = run_share(ann.current.instance, seg, ann.current.num_instances)
    assert np.isnan(state.query_scores[b])
    np.testing.assert_allclose(state.query_scores[a], share[a] @ raw, rtol=1e-5)

    # a split, then an update computed from that labelling: the split-off id is ranked after it
    big = int(np.argmax(np.bincount(seg.instance[seg.instance >= 0])))
    pts = np.flatnonzero(ann.current.instance == big)
    ann.apply_op(Split(points=tuple(pts[: len(pts) // 2].tolist()), source=big))
    k = ann.current.num_instances - 1
    run = ann.run_dir
    s0 = state_from_run(run)
    r1 = _fake_update(s0, 8, k=a, shift=0.05, removed=None, n_iter=3)
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    d = load_viewer_data(run, images=False)
    from clutt3r_viewer.scene_step import shown_scene

    step["now"] = 1
    s.app.data = d
    s.scene = lambda: shown_scene(d, 1, np.arange(len(seg.points)))
    panel.run_query(s, "red")
    sc = state.query_scores
    assert np.isfinite(sc[k]) and np.isfinite(sc[a]) and np.isnan(sc[b]), panel.result.content
    share = run_share(ann.current.instance, seg, ann.current.num_instances)
    np.testing.assert_allclose(sc[k], share[k] @ raw, rtol=1e-5)


def test_an_edit_ranks_the_last_query_again_only_while_the_run_itself_is_shown(monkeypatch):
    """After updates the scene shown has the chain's ids, which no edit changes: an edit there does not
    run the query again (it did, for the same result); another scene shown or an edit at step 0 does."""
    from clutt3r_viewer.panels.base import Change

    class Now:  # the refresh's thread, run at once
        def __init__(self, target, args, daemon):
            self.target, self.args = target, args

        def start(self):
            self.target(*self.args)

    monkeypatch.setattr(qp.threading, "Thread", Now)
    panel, calls, step = qp.QueryPanel(), [], {"now": 1}
    monkeypatch.setattr(panel, "run_query", lambda s, text, show=True: calls.append((step["now"], text, show)))
    s = SimpleNamespace(state=SimpleNamespace(query="red"), scene_step=lambda: step["now"])
    panel.refresh(s, Change.LABELS)
    assert calls == []
    panel.refresh(s, Change.SCENE)
    step["now"] = 0
    panel.refresh(s, Change.LABELS)
    panel.refresh(s, Change.COLOUR)
    s.state.query = ""
    panel.refresh(s, Change.SCENE | Change.LABELS)
    assert calls == [(1, "red", False), (0, "red", False)]
