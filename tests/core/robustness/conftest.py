"""Fixtures of the robustness tests: one small scene written to disk once per session."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from clutt3r_core.io import write_sample_layout
from tests.core.robustness._scenes import make_scene


@pytest.fixture(scope="session")
def _scene_on_disk(tmp_path_factory) -> Path:
    return write_sample_layout(make_scene(3, width=160, height=120), tmp_path_factory.mktemp("robust") / "scene")


@pytest.fixture
def scene_dir(_scene_on_disk: Path, tmp_path: Path) -> Path:
    """A fresh copy of a valid 3-view sample-layout scene (160x120, two boxes), free to break."""
    return Path(shutil.copytree(_scene_on_disk, tmp_path / "scene"))
