"""Shared fixtures: paths of the real samples (skipped with a clear message when absent)."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SAMPLES = REPO.parent / "shared" / "data" / "clutt3r-samples"


def sample_dir(name: str) -> Path:
    d = SAMPLES / name / "data"
    if not d.is_dir():
        pytest.skip(f"real sample data not found at {d} (needs ../shared/data/clutt3r-samples beside the repo)")
    return d


@pytest.fixture
def seq1_dir() -> Path:
    return sample_dir("sample_seq1")


@pytest.fixture
def seq4_dir() -> Path:
    return sample_dir("sample_seq4")
