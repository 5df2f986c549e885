"""``commands.segment_run.plain_arguments``: the command lines ``clutt3r segment`` runs without
building tyro's parser (issue 13, ~0.14 s of CPU per process). Whatever it accepts, tyro must
parse to the same call; everything else is left to tyro."""

from __future__ import annotations

import functools
import inspect
from pathlib import Path

import pytest
import tyro
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.commands.masks import MaskOptions
from clutt3r_core.commands.segment import segment_command
from clutt3r_core.commands.segment_run import plain_arguments
from clutt3r_core.config import SegmentConfig


def _tyro(args: list[str]) -> dict | None:
    """What tyro passes to segment_command for ``args`` (all arguments, defaults filled), or None
    when it refuses them."""
    sig = inspect.signature(segment_command)
    got: dict = {}

    @functools.wraps(segment_command)
    def capture(*a, **k):
        b = sig.bind(*a, **k)
        b.apply_defaults()
        got.update(b.arguments)

    try:
        tyro.cli(capture, prog="clutt3r segment", args=args)
    except SystemExit:
        return None
    return got


def _same_call(args: list[str]) -> None:
    plain = plain_arguments(args)
    if plain is None:
        return
    parsed = _tyro(args)
    assert parsed is not None, f"accepted {args}, which tyro refuses"
    scene, out, preset = plain
    # a parameter segment_command gains must be passed by the plain path too (cli._segment_without_parser)
    assert set(parsed) == {"scene", "out", "config", "preset", "mask_options"}, sorted(parsed)
    assert (parsed["scene"], parsed["out"], parsed["preset"]) == (scene, out, preset), args
    assert parsed["config"] == SegmentConfig() and parsed["mask_options"] == MaskOptions(), args


@pytest.mark.parametrize("args", [
    ["scene", "--out", "run"],
    ["--out", "run", "scene"],
    ["scene", "--out=run"],
    ["a b/scene", "--out", "r=1", "--preset", "paper"],
    ["scene", "--preset=noisy-depth", "--out", "run"],
])
def test_the_plain_forms_are_recognised_and_tyro_agrees(args, capsys):
    assert plain_arguments(args) is not None
    _same_call(args)


@pytest.mark.parametrize("args", [
    [], ["scene"], ["--out", "run"], ["scene", "--out"], ["scene", "--out", "run", "--help"],
    ["scene", "--out", "a", "--out", "b"], ["scene", "other", "--out", "run"], ["scene", "--out", "-run"],
    ["scene", "--out", "run", "--preset", "bogus"], ["scene", "--out", "run", "--preset="],
    ["scene", "--out", "run", "--masks", "builtin"], ["scene", "--out", "run", "--config.vote.min-points", "5"],
    ["--", "scene", "--out", "run"], ["scene", "--ou", "run"], ["-", "--out", "run"],
])
def test_everything_else_goes_to_tyro(args):
    assert plain_arguments(args) is None


_WORDS = ["scene", "s2", "--out", "--out=run", "run", "--preset", "paper", "noisy-depth", "--preset=paper",
          "--preset=bogus", "bogus", "--masks", "builtin", "--config.vote.min-points", "5", "-", "--", "-x", "",
          "--help", "--ou"]


@settings(max_examples=150, deadline=None)
@given(st.lists(st.sampled_from(_WORDS), max_size=7))
def test_whatever_is_accepted_tyro_parses_to_the_same_call(words):
    _same_call(words)


def test_a_plain_segment_process_never_imports_tyro(tmp_path: Path):
    import json
    import subprocess
    import sys

    from clutt3r_core.io import write_sample_layout
    from tests.core.robustness._scenes import make_scene

    scene = write_sample_layout(make_scene(3, width=160, height=120), tmp_path / "scene")
    prog = ("import atexit, json, sys\n"
            "atexit.register(lambda: sys.__stdout__.write('MODULES=' + json.dumps(sorted(sys.modules)) + '\\n'))\n"
            "from clutt3r_core.cli import main\nmain(sys.argv[1:])\n")
    for extra, tyro_loaded in (([], False), (["--masks", "auto"], True)):  # the second: tyro parses
        out = tmp_path / f"run{len(extra)}"
        r = subprocess.run([sys.executable, "-c", prog, "segment", str(scene), "--out", str(out), *extra],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        mods = json.loads([x for x in r.stdout.splitlines() if x.startswith("MODULES=")][-1][len("MODULES="):])
        assert ("tyro" in mods) is tyro_loaded
        assert (out / "instances.npz").is_file() and (out / "overview.png").is_file()


def test_a_finished_segment_process_ends_without_teardown_but_runs_its_exit_handlers(tmp_path: Path):
    """``main()`` as the program (no argv) ends the process after a plain segment run (issue 13:
    the interpreter's teardown was 40-70 ms); atexit handlers run, output is flushed, the exit
    status is 0. Called with an argument list (a library call), it returns as before."""
    import subprocess
    import sys

    from clutt3r_core.io import write_sample_layout
    from tests.core.robustness._scenes import make_scene

    scene = write_sample_layout(make_scene(3, width=160, height=120), tmp_path / "scene")
    for call, ended in (("main()", True), ("main(sys.argv[1:])", False)):
        out = tmp_path / f"run_{ended}"
        prog = ("import atexit, sys\n"
                "atexit.register(lambda: sys.stdout.write('EXIT HANDLER\\n'))\n"
                "sys.stdout.write('buffered before\\n')\n"
                f"from clutt3r_core.cli import main\n{call}\n"
                "sys.stdout.write('AFTER MAIN\\n')\n")
        r = subprocess.run([sys.executable, "-c", prog, "segment", str(scene), "--out", str(out)],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr[-2000:]
        assert "buffered before" in r.stdout and "EXIT HANDLER" in r.stdout
        assert ("AFTER MAIN" in r.stdout) is not ended
        # the summary line was flushed (rich wraps it at the terminal width, even inside the path)
        assert f"->{out}" in "".join(r.stderr.split())
        assert (out / "overview.png").is_file() and (out / "run.json").is_file()
