"""The panel structure: typed handles, one module per panel, nothing string-keyed."""

from __future__ import annotations

import re
from pathlib import Path

from clutt3r_viewer.panels import PANELS, Panel

VIEWER = Path(__file__).resolve().parents[2] / "clutt3r_viewer"


def test_every_panel_declares_its_handles_with_types():
    assert len({p.__module__ for p in PANELS}) >= 9  # one module per panel (Scene + Instances share one)
    for cls in PANELS:
        assert issubclass(cls, Panel)
        import importlib

        import viser

        ns = {**vars(importlib.import_module(cls.__module__)), "viser": viser}
        own = dict(vars(cls).get("__annotations__", {}))
        own.pop("tab", None)
        assert own, f"{cls.__name__} declares no handle attributes"
        for name, ann in own.items():  # every annotation names real types (viser handles, builtins)
            eval(ann, ns) if isinstance(ann, str) else ann


def test_no_string_keyed_handle_dicts_and_small_modules():
    for f in VIEWER.rglob("*.py"):
        src = f.read_text()
        assert not re.search(r"self\.h\[|self\.h: dict|\bh\[\"", src), f"string-keyed handles in {f.name}"
        assert len(src.splitlines()) <= 500, f"{f} over 500 lines"
