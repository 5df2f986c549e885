"""Layout rules of the whole product (issue 8 acceptance): no import cycles across the core and the
viewer, and no module over ~500 lines without the reason in its docstring."""

from __future__ import annotations

import ast
from pathlib import Path

from tests.core.test_structure import _cycles, _module_level_imports

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("clutt3r_core", "clutt3r_viewer")
MAX_LINES = 520  # "about 500"


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for p in sorted((ROOT / pkg).rglob("*.py")):
            parts = list(p.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            out[".".join(parts)] = p
    return out


def test_no_import_cycles_in_core_and_viewer():
    mods = _modules()
    graph = {n: sorted(m for m in _module_level_imports(n, p) if m in mods and m != n) for n, p in mods.items()}
    cycles = _cycles(graph)
    assert not cycles, "import cycles: " + "; ".join(" -> ".join(c) for c in cycles)


def test_long_modules_say_why():
    bad = []
    for name, p in _modules().items():
        text = p.read_text()
        n = text.count("\n")
        if n > MAX_LINES:
            doc = ast.get_docstring(ast.parse(text)) or ""
            if "on purpose" not in doc:
                bad.append(f"{name}: {n} lines and no 'on purpose' reason in its docstring")
    assert not bad, bad
