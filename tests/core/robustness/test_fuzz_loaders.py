"""Fuzzed scene loaders (issue 14): random corruptions of transforms.json, BOP camera files,
PNG bytes and npz files never raise anything but the project's typed errors; nor do
corrupted run folders (run.json, trace.json, the run's npz files) read by ``load_run``.

Bounded here (CI); ``benchmarks/fuzz_loaders.py`` runs the same property for minutes.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
from hypothesis import HealthCheck, example, given, settings

from clutt3r_core.io.images import npz_bytes

from tests.core.robustness._fuzz import apply, check_loads, check_run_loads, corruptions, run_corruptions

_SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _check(c) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        check_loads(apply(c, Path(tmp)))


@_SETTINGS
@given(corruptions(kinds=("json",)))
@example(("sample", "gt/objects.json", b"[null]"))  # found by the long run: AttributeError
@example(("sample", "transforms.json", b'{"fl_x": 1, "fl_y": 1, "cx": 0, "cy": 0, "w": 32, "h": 24, "frames": '
          b'[{"file_path": null, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,0,1]]}]}'))  # TypeError
def test_fuzz_json_files(c):
    _check(c)


@_SETTINGS
@given(corruptions(kinds=("png",)))
def test_fuzz_png_bytes(c):
    _check(c)


@_SETTINGS
@given(corruptions(kinds=("npz",)))
@example(("sample", "gt/points.npz", npz_bytes(points=np.float32(1), labels=np.float32(1))))  # was ValueError
def test_fuzz_npz_files(c):
    _check(c)


@_SETTINGS
@given(run_corruptions())
def test_fuzz_run_folders(c):
    with tempfile.TemporaryDirectory() as tmp:
        check_run_loads(apply(c, Path(tmp)))


def test_bop_translation_beyond_a_km_is_refused_without_numpy_warnings(tmp_path):
    # found by the long fuzz run: 1e300 mm was finite, so it passed, and overflowed in the GT grid
    import json
    import shutil
    import warnings

    import pytest

    from clutt3r_core.errors import SceneFileError
    from clutt3r_core.io import load_scene
    from tests.core.robustness._fuzz import base_scenes

    root = Path(shutil.copytree(base_scenes()["bop"], tmp_path / "bop"))
    cams = json.loads((root / "scene_camera.json").read_text())
    cams["1"]["cam_t_w2c"] = [1e300, 0.0, 0.0]
    (root / "scene_camera.json").write_text(json.dumps(cams))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a numpy RuntimeWarning would reach the user's terminal
        with pytest.raises(SceneFileError, match="image 1: cam_R_w2c/cam_t_w2c: translation of 1e\\+297 m is implausible"):
            load_scene(root)
