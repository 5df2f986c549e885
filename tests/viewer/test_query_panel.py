"""The Query tab's language-backend path (clutt3r_core.query), driven without a browser: scores
become the ``query`` colour layer's input, the best instance is highlighted, and the tab
explains the ranking. The backend is the wiring fake of tests/core/query/_fake.py."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np

import clutt3r_core.query as cq
import clutt3r_viewer.panels.query as qp
from tests.core.query._fake import FakeGrounder


def _session(data):
    state = SimpleNamespace(query="", query_best=-1, query_scores=None, color_mode="instance")
    changes = []
    s = SimpleNamespace(app=SimpleNamespace(text_embedder=None, data=data), lock=threading.Lock(), state=state,
                        changed=changes.append, scene_step=lambda: 0)  # the run itself (no update shown)
    return s, changes


def test_language_query_sets_heat_map_best_and_reason(tiny_data, monkeypatch):
    monkeypatch.setattr(qp, "language_backend_name", lambda: "fake-ground")
    monkeypatch.setattr(cq, "create_grounder", lambda name=None: FakeGrounder())
    s, changes = _session(tiny_data)
    panel = qp.QueryPanel()
    panel.result = SimpleNamespace(content="")
    panel.run_query(s, "the red thing")
    st = s.state
    assert st.color_mode == "query" and changes
    assert st.query_scores is not None and len(st.query_scores) == tiny_data.seg.num_instances
    assert st.query_best == int(np.argmax(st.query_scores))
    assert f"→ I{st.query_best}" in panel.result.content and "| why |" in panel.result.content
    rq = s.app._run_query
    panel.run_query(s, "blue thing")  # the evidence is built once per app
    assert s.app._run_query is rq
    panel.run_query(s, "   ")
    assert st.query_scores is None and st.query_best == -1 and st.color_mode == "instance"


def test_query_failure_is_shown_not_raised(tiny_data, monkeypatch):
    monkeypatch.setattr(qp, "language_backend_name", lambda: "fake-ground")

    def boom(name=None):
        raise RuntimeError("no weights")

    monkeypatch.setattr(cq, "create_grounder", boom)
    s, _ = _session(tiny_data)
    panel = qp.QueryPanel()
    panel.result = SimpleNamespace(content="")
    panel.run_query(s, "mug")
    assert "query failed" in panel.result.content and s.state.query_scores is None
