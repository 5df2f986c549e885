"""The one backend registry: lookup, defaults, missing extras, protocol checks, plugins."""

from __future__ import annotations

import re
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from clutt3r_core import registry as reg
from clutt3r_core.errors import Clutt3rError, MissingDependencyError
from clutt3r_core.registry import KINDS, Registry

ROOT = Path(__file__).resolve().parents[2]


class _Planner:
    name = "fake"

    def plan(self, request):
        return request


def test_every_kind_has_a_protocol_that_imports():
    for kind in KINDS:
        proto = reg._import_attr(reg.PROTOCOLS[kind])
        assert getattr(proto, "_is_runtime_protocol", False), kind


def test_builtin_backends_are_listed_and_buildable():
    assert "appearance-hsv" in reg.backend_names("mask_embedder")
    emb = reg.create_backend("mask_embedder", "appearance-hsv")
    out = emb.embed_masks(np.zeros((4, 4, 3), np.uint8), np.ones((1, 4, 4), bool))
    assert out.shape == (1, emb.dim)
    # the bench methods share one factory; the registry passes each its own name
    m = reg.create_backend("bench_method", "naive")
    assert m.name == "naive"
    assert reg.default_backend("bench_method") == "ours"


def test_missing_package_fails_at_construction_naming_the_extra():
    r = Registry()
    r.register("grasp_planner", "needs-pkg", _Planner, requires=("no_such_module_xyz=no-such-pkg",), extra="fancy")
    st = r.status("grasp_planner")[0]
    assert not st.available and st.missing == ("no-such-pkg",)
    assert st.hint == "pip install 'clutt3r[fancy]'"
    with pytest.raises(MissingDependencyError, match=r"no-such-pkg.*clutt3r\[fancy\]"):
        r.create("grasp_planner", "needs-pkg")
    # an unavailable backend is never the default, whatever its priority
    r.register("grasp_planner", "plain", _Planner)
    r.register("grasp_planner", "needs-pkg", _Planner, requires=("no_such_module_xyz",), priority=10)
    assert r.default("grasp_planner") == "plain"


def test_unknown_names_and_kinds_are_clear_errors():
    r = Registry()
    r.register("grasp_planner", "a", _Planner)
    with pytest.raises(Clutt3rError, match="unknown grasp planner 'b'; registered: a"):
        r.create("grasp_planner", "b")
    with pytest.raises(Clutt3rError, match="unknown backend kind"):
        r.names("teleporter")
    with pytest.raises(Clutt3rError, match="no pose optimizer is available"):
        r.create("pose_optimizer")


def test_object_not_implementing_the_protocol_is_refused():
    r = Registry()
    r.register("grasp_planner", "wrong", lambda: SimpleNamespace(name="wrong"))
    with pytest.raises(Clutt3rError, match="does not implement"):
        r.create("grasp_planner", "wrong")


def test_entry_point_plugins_register_and_broken_ones_are_reported(monkeypatch):
    calls = []

    class _EP:
        def __init__(self, name, fn):
            self.name, self.value, self._fn = name, f"pkg:{name}", fn

        def load(self):
            return self._fn

    def good(registry):
        calls.append("good")
        registry.register("grasp_planner", "plugin-planner", _Planner)

    def bad(registry):
        raise RuntimeError("boom")

    monkeypatch.setattr(reg, "entry_points", lambda group: [_EP("good", good), _EP("bad", bad)])
    r = Registry()
    with pytest.warns(RuntimeWarning, match="plugin 'bad'"):
        names = r.names("grasp_planner")
    assert names == ("plugin-planner",) and calls == ["good"]
    assert r.get("grasp_planner", "plugin-planner").source == "entry point good"
    assert any("boom" in e for e in r.plugin_errors)
    r.names("grasp_planner")
    assert calls == ["good"]  # plugins load once


def test_architecture_doc_plugin_example_runs():
    # The ten-line example of docs/architecture.md must stay true.
    text = (ROOT / "docs" / "architecture.md").read_text()
    code = re.search(r"```python\n(# my_pkg/clutt3r_plugin.py.*?)```", text, re.S).group(1)
    ns: dict = {}
    exec(compile(code, "architecture.md", "exec"), ns)
    r = Registry()
    ns["register"](r)
    gen = r.create("mask_generator", "halves")
    view = SimpleNamespace(rgb=np.zeros((6, 8, 3), np.uint8))
    cands = gen.generate(view)
    assert cands.masks.shape == (3, 6, 8)
    assert cands.masks[1].sum() + cands.masks[2].sum() == cands.masks[0].sum()
