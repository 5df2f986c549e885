"""update.prefetch_optimizer: the pose optimiser's import (torch) on a background thread, only
when the view will be fitted by silhouette; once per process; failures left to construction."""

from __future__ import annotations

import sys
from dataclasses import replace

import pytest

pytest.importorskip("torch")

from clutt3r_core.update import update as U  # noqa: E402
from clutt3r_core.update.types import UpdateConfig  # noqa: E402

from ._scenes import camera, render_view, two_box_scene  # noqa: E402


@pytest.fixture
def fresh(monkeypatch):
    monkeypatch.setattr(U, "_PREFETCH", {})


def _view(with_depth: bool):
    pts, cols, inst = two_box_scene()
    return render_view(pts, cols, inst, camera(), with_depth=with_depth)


def test_no_prefetch_when_the_depth_registration_moves_the_instances(fresh) -> None:
    assert U.prefetch_optimizer(_view(True), UpdateConfig()) is None
    assert U._PREFETCH == {}


def test_prefetch_without_depth_imports_the_backend_once(fresh) -> None:
    view = _view(False)
    th = U.prefetch_optimizer(view, UpdateConfig())
    assert th is not None and th.daemon
    th.join(120)
    assert not th.is_alive() and "torch" in sys.modules and "clutt3r_core.update.pose" in sys.modules
    assert U.prefetch_optimizer(view, UpdateConfig()) is th  # once per process and backend


def test_prefetch_with_depth_when_the_registration_is_refined(fresh) -> None:
    cfg = UpdateConfig()
    cfg = replace(cfg, pose=replace(cfg.pose, refine_registration=True))
    th = U.prefetch_optimizer(_view(True), cfg)
    assert th is not None
    th.join(120)


def test_prefetch_of_an_unknown_backend_fails_quietly(fresh) -> None:
    """The thread swallows the error: constructing the optimiser reports it (naming the extra)."""
    cfg = replace(UpdateConfig(), optimizer="no-such-optimizer")
    th = U.prefetch_optimizer(_view(False), cfg)
    th.join(30)
    assert not th.is_alive()
