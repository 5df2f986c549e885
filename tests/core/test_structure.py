"""Static checks of the core's layering: every module imports, the core never imports the viewer,
there are no import cycles at module level, and algorithm modules do not import the CLI library."""

from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

import clutt3r_core

_ROOT = Path(clutt3r_core.__file__).parent


def _modules() -> dict[str, Path]:
    out = {}
    for p in sorted(_ROOT.rglob("*.py")):
        parts = list(p.relative_to(_ROOT.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        out[".".join(parts)] = p
    return out


MODULES = _modules()


def _module_level_imports(name: str, path: Path) -> set[str]:
    """Modules imported when ``name`` is imported: top-level statements only (not inside functions,
    classes' methods or ``if TYPE_CHECKING:``), resolved to full dotted names, parents included."""
    tree = ast.parse(path.read_text(), str(path))
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()

    def visit(stmts):
        for node in stmts:
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                found.add(mod)
                found.update(f"{mod}.{a.name}" for a in node.names)  # "from pkg import module"
            elif isinstance(node, ast.If):
                t = node.test
                if (isinstance(t, ast.Name) and t.id == "TYPE_CHECKING") or (
                    isinstance(t, ast.Attribute) and t.attr == "TYPE_CHECKING"
                ):
                    continue
                visit(node.body)
                visit(node.orelse)
            elif isinstance(node, (ast.Try,)):
                visit(node.body)
                for h in node.handlers:
                    visit(h.body)
                visit(node.orelse)
                visit(node.finalbody)

    visit(tree.body)
    # importing a.b.c imports a and a.b first
    out = set()
    for m in found:
        parts = m.split(".")
        out.update(".".join(parts[: i + 1]) for i in range(len(parts)))
    return out


@pytest.mark.parametrize("name", [m for m in MODULES if not m.endswith("__main__")])
def test_every_module_imports(name):
    importlib.import_module(name)


def test_the_core_never_imports_the_viewer():
    bad = []
    for name, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):  # inside functions too
            mods = []
            if isinstance(node, ast.Import):
                mods = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module:
                mods = [node.module]
            bad += [f"{name} imports {m}" for m in mods if m.split(".")[0] == "clutt3r_viewer"]
    assert not bad, bad


def _cycles(graph: dict[str, list[str]]) -> list[list[str]]:
    cycles = []
    state: dict[str, int] = {}  # 1 = on the stack, 2 = done
    stack: list[str] = []

    def dfs(n: str) -> None:
        state[n] = 1
        stack.append(n)
        for m in graph.get(n, ()):
            if state.get(m) == 1:
                cycles.append(stack[stack.index(m):] + [m])
            elif m not in state:
                dfs(m)
        stack.pop()
        state[n] = 2

    for n in graph:
        if n not in state:
            dfs(n)
    # a package's __init__ importing its own submodules is not a cycle of the code's layering
    return [c for c in cycles if not all(x == c[0] or x.startswith(c[0] + ".") or c[0].startswith(x + ".") for x in c)]


def test_no_import_cycles_at_module_level():
    graph = {n: sorted(m for m in _module_level_imports(n, p) if m in MODULES and m != n) for n, p in MODULES.items()}
    real = _cycles(graph)
    assert not real, "import cycles: " + "; ".join(" -> ".join(c) for c in real)


def test_the_scan_sees_cycles_and_skips_function_level_imports(tmp_path):
    assert _cycles({"p.a": ["p.b"], "p.b": ["p.c"], "p.c": ["p.a"]}) == [["p.a", "p.b", "p.c", "p.a"]]
    assert _cycles({"p": ["p.a"], "p.a": ["p"]}) == []  # package __init__ and its submodule
    f = tmp_path / "m.py"
    f.write_text(
        "from typing import TYPE_CHECKING\n"
        "from clutt3r_core.evaluation import runner\n"
        "from . import sibling\n"
        "if TYPE_CHECKING:\n    import clutt3r_core.pipeline\n"
        "def f():\n    import clutt3r_core.runs\n"
    )
    got = _module_level_imports("clutt3r_core.evaluation.m", f)
    assert {"clutt3r_core.evaluation.runner", "clutt3r_core.evaluation.sibling", "clutt3r_core"} <= got
    assert "clutt3r_core.pipeline" not in got and "clutt3r_core.runs" not in got


def test_algorithm_modules_do_not_import_tyro():
    # CLI commands live in clutt3r_core/commands/ (and synth/cli.py, cli.py)
    allowed = {"clutt3r_core.cli", "clutt3r_core.synth.cli"}
    bad = [
        n for n, p in MODULES.items()
        if not n.startswith("clutt3r_core.commands") and n not in allowed
        and any(m.split(".")[0] == "tyro" for m in _module_level_imports(n, p))
    ]
    assert not bad, bad
