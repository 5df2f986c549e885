"""Fuzzed scene loaders (issue 14): random corruptions of transforms.json, BOP camera files,
PNG bytes and npz files never raise anything but the project's typed errors.

Bounded here (CI); ``benchmarks/fuzz_loaders.py`` runs the same property for minutes.
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from hypothesis import HealthCheck, given, settings

from tests.core.robustness._fuzz import apply, check_loads, corruptions

_SETTINGS = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _check(c) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        check_loads(apply(c, Path(tmp)))


@_SETTINGS
@given(corruptions(kinds=("json",)))
def test_fuzz_json_files(c):
    _check(c)


@_SETTINGS
@given(corruptions(kinds=("png",)))
def test_fuzz_png_bytes(c):
    _check(c)


@_SETTINGS
@given(corruptions(kinds=("npz",)))
def test_fuzz_npz_files(c):
    _check(c)
