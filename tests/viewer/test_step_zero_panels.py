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
