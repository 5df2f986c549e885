"""``commands.scene_prefetch``: ``clutt3r segment`` starts loading its scene before tyro parses the
command line (issue 13, whole-command time). The guess never decides anything: the command takes
the prefetched scene only when tyro's SCENE is the same path, and a loading error surfaces where
the command would have raised it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.cli import main
from clutt3r_core.commands import scene_prefetch
from clutt3r_core.errors import SceneFileError
from clutt3r_core.io import load_scene, write_sample_layout
from clutt3r_core.runs import load_run
from tests.core.robustness._scenes import make_scene


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    return write_sample_layout(make_scene(3, width=160, height=120), tmp_path_factory.mktemp("s") / "scene")


@pytest.fixture(autouse=True)
def _nothing_pending():
    scene_prefetch._pending = None
    yield
    scene_prefetch._pending = None


def test_the_one_scene_folder_among_the_arguments_is_guessed(scene_dir, tmp_path):
    s = str(scene_dir)
    assert scene_prefetch.scene_argument([s, "--out", str(tmp_path / "run")]) == scene_dir
    assert scene_prefetch.scene_argument(["--out", str(tmp_path / "run"), "--preset", "paper", s]) == scene_dir
    tj = scene_dir / "transforms.json"
    assert scene_prefetch.scene_argument([str(tj), "--out", "x"]) == tj
    # none, two, a folder that is not a scene, or --help (tyro answers it and exits): no guess
    assert scene_prefetch.scene_argument(["--out", "x"]) is None
    assert scene_prefetch.scene_argument([s, "--out", s]) is None
    assert scene_prefetch.scene_argument([str(tmp_path), "--out", "x"]) is None
    assert scene_prefetch.scene_argument([s, "--help"]) is None
    assert scene_prefetch.start([s, "-h"]) is False and scene_prefetch._pending is None


@settings(max_examples=60, deadline=None)
@given(st.lists(st.sampled_from(["SCENE", "OTHER_DIR", "--out", "RUN", "--preset", "paper", "--config.vote.x", "-"]),
                max_size=8))
def test_a_guess_is_made_exactly_when_one_argument_names_a_scene(scene_dir, tmp_path_factory, words):
    other = tmp_path_factory.getbasetemp()  # a folder, not a scene
    args = [str(scene_dir) if w == "SCENE" else str(other) if w == "OTHER_DIR" else w for w in words]
    got = scene_prefetch.scene_argument(args)
    assert got == (scene_dir if words.count("SCENE") == 1 else None)


def test_take_hands_over_only_the_scene_that_was_parsed(scene_dir, tmp_path):
    assert scene_prefetch.take(scene_dir) is None  # nothing started (a library call of the command)
    assert scene_prefetch.start([str(scene_dir), "--out", str(tmp_path / "r")])
    got = scene_prefetch.take(scene_dir)
    want = load_scene(scene_dir, load_gt=False)
    assert got is not None and got.name == want.name and len(got.views) == len(want.views)
    for a, b in zip(got.views, want.views):
        np.testing.assert_array_equal(a.rgb, b.rgb)
        np.testing.assert_array_equal(a.depth, b.depth)
    assert scene_prefetch.take(scene_dir) is None  # handed over once
    # tyro parsed another SCENE than the guess: the prefetched scene is not used
    assert scene_prefetch.start([str(scene_dir)])
    assert scene_prefetch.take(tmp_path / "elsewhere") is None


def test_a_loading_error_is_raised_by_take(scene_dir, tmp_path):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(scene_dir, broken)
    rgb = sorted((broken / "images").iterdir())[0]
    rgb.write_bytes(rgb.read_bytes()[:100])  # cut short
    with pytest.raises(SceneFileError) as direct:
        load_scene(broken, load_gt=False)
    assert scene_prefetch.start([str(broken)])
    with pytest.raises(SceneFileError) as taken:
        scene_prefetch.take(broken)
    assert str(taken.value) == str(direct.value)


def test_the_cli_run_equals_the_command_without_prefetch(scene_dir, tmp_path, capsys):
    from clutt3r_core.commands.segment import segment_command

    main(["segment", str(scene_dir), "--out", str(tmp_path / "cli")])
    assert scene_prefetch._pending is None  # the command took the prefetched scene
    segment_command(scene_dir, tmp_path / "direct")
    a, b = load_run(tmp_path / "cli"), load_run(tmp_path / "direct")
    for k in ("points", "instance", "scores", "normals", "sv_labels"):
        np.testing.assert_array_equal(getattr(a, k), getattr(b, k))
    assert (a.instance >= 0).any()


def test_a_broken_scene_still_gives_one_error_line(scene_dir, tmp_path, capsys):
    import shutil

    broken = tmp_path / "broken"
    shutil.copytree(scene_dir, broken)
    (broken / "transforms.json").write_text("{not json")
    # transforms.json is what marks a scene folder, so the guess is made and the loading fails
    with pytest.raises(SystemExit) as e:
        main(["segment", str(broken), "--out", str(tmp_path / "run")])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "transforms.json" in err[0] and "not valid JSON" in err[0], err


def test_a_scene_the_command_did_not_take_is_not_handed_to_a_later_call(scene_dir, tmp_path, capsys):
    """tyro refuses the line after the scene began loading: the prefetched copy is dropped, so
    the command called later in the same process reads the scene as it is then."""
    import shutil

    from clutt3r_core.commands.segment import segment_command

    scene = tmp_path / "scene"
    shutil.copytree(scene_dir, scene)
    with pytest.raises(SystemExit):
        main(["segment", str(scene), "--out", str(tmp_path / "r0"), "--no-such-option"])
    assert scene_prefetch._pending is None
    (scene / "transforms.json").write_text("{not json")  # broken after the refused call
    with pytest.raises(SceneFileError, match="not valid JSON"):
        segment_command(scene, tmp_path / "r1")
