"""The views panel's Candidates selector against a real viser server (no browser): another
generator's candidates are generated in the background, shown, cached per (view, generator),
and switching back restores the run's own overlay."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np
import pytest

from clutt3r_viewer.panels.views import RUN, ViewsPanel, candidates_overlay, mask_generators, overlay_image
from clutt3r_viewer.state import Change, SessionState
from tests.viewer.conftest import free_port

pytestmark = pytest.mark.filterwarnings("ignore:Got image with third dimension")


class _Counting:
    def __init__(self, gen):
        self.gen, self.name, self.calls = gen, gen.name, []

    def generate(self, view):
        self.calls.append(view.frame)
        return self.gen.generate(view)


class _Broken:
    name = "broken"

    def generate(self, view):
        raise RuntimeError("no model here")


def _wait(p):
    for _ in range(3):  # a finished worker may start the next generation the selection needs
        w = p.worker
        if w is None:
            return
        w.join(timeout=120)
        assert not w.is_alive(), "generation did not finish"


def test_registry_lists_buildable_generators_only():
    gens = mask_generators()
    assert "builtin" in gens
    assert "import" not in gens and "sam-onnx" not in gens  # need a source / model paths


def test_switch_to_builtin_and_back(tiny_data):
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    notes = []

    def add_notification(title, body, **kw):
        notes.append(SimpleNamespace(title=title, body=body, first_body=body, **kw))
        return notes[-1]

    try:
        s = SimpleNamespace(client=SimpleNamespace(gui=server.gui, add_notification=add_notification),
                            lock=threading.RLock(), state=SessionState(), closed=False, select_view=lambda vi: None,
                            app=SimpleNamespace(data=tiny_data, no_images_text=None))
        p = ViewsPanel()
        p.build(s)
        assert p.candidates is not None and p.candidates.value == RUN and "builtin" in p.candidates.options
        run0 = p.image.image.copy()
        assert np.array_equal(run0, overlay_image(tiny_data, 0))
        gen = p.generators["builtin"] = _Counting(p.generators["builtin"])

        p.select_candidates(s, "builtin")
        _wait(p)
        cands = p.generated[(0, "builtin")]
        view0 = tiny_data.views[0]
        shown = p.image.image
        assert np.array_equal(shown, candidates_overlay(view0, cands, tiny_data.trace.config.trees))
        assert not np.array_equal(shown, run0)  # other candidates, other overlay
        assert "builtin candidates" in p.image.label
        assert notes[0].first_body.startswith("generating builtin") and notes[0].loading is False  # finished
        assert f"{len(cands)} candidates" in notes[0].body

        p.select_candidates(s, RUN)
        assert np.array_equal(p.image.image, run0) and p.worker is None

        p.select_candidates(s, "builtin")  # cached: shown at once, not generated again
        assert p.worker is None and gen.calls == [view0.frame]
        assert np.array_equal(p.image.image, shown)

        s.state.view = 1  # another view while builtin is selected: generated for it
        p.refresh(s, Change.VIEW)
        _wait(p)
        assert gen.calls == [view0.frame, tiny_data.views[1].frame]
        assert not np.array_equal(p.image.image, shown)
        p.refresh(s, Change.NODE)  # a node selection leaves another generator's overlay alone
        assert len(gen.calls) == 2

        p.generators["broken"] = _Broken()  # a failing generator: told, and back to the run's
        p.candidates.options = [*p.candidates.options, "broken"]
        p.select_candidates(s, "broken")
        _wait(p)
        assert "failed" in notes[-1].body and "no model here" in notes[-1].body
        assert p.candidates.value == RUN
        assert np.array_equal(p.image.image, overlay_image(tiny_data, 1))
    finally:
        server.stop()
