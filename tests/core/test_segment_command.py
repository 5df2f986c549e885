"""``clutt3r segment`` writes the run and overview.png (drawn on a thread while the run is
saved, issue 13): the picture is the one ``overview_sheet`` draws, and its errors still surface."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from clutt3r_core.commands.segment import segment_command
from clutt3r_core.io import load_scene, write_sample_layout
from clutt3r_core.runs import load_run
from clutt3r_core.visualize import overview_sheet
from tests.core.robustness._scenes import make_scene


@pytest.fixture(scope="module")
def scene_dir(tmp_path_factory) -> Path:
    return write_sample_layout(make_scene(3, width=160, height=120), tmp_path_factory.mktemp("s") / "scene")


def test_overview_png_is_the_overview_of_the_saved_run(scene_dir, tmp_path):
    segment_command(scene_dir, tmp_path / "run")
    run = load_run(tmp_path / "run")
    got = cv2.cvtColor(cv2.imread(str(tmp_path / "run" / "overview.png")), cv2.COLOR_BGR2RGB)
    want = overview_sheet(run.points, run.instance, load_scene(scene_dir))
    assert (run.instance >= 0).any()  # something was painted: the comparison is not of two bare views
    np.testing.assert_array_equal(got, want)


def test_an_error_while_drawing_the_overview_is_raised(scene_dir, tmp_path, monkeypatch):
    import clutt3r_core.visualize as vis

    def broken(*a, **k):
        raise RuntimeError("drawing failed")

    monkeypatch.setattr(vis, "overview_sheet", broken)
    with pytest.raises(RuntimeError, match="drawing failed"):
        segment_command(scene_dir, tmp_path / "run")
    assert (tmp_path / "run" / "instances.npz").is_file()  # the run itself was saved
    assert not (tmp_path / "run" / "overview.png").exists()
