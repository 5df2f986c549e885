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
