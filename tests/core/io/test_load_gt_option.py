"""``load_scene(..., load_gt=False)``: what ``clutt3r segment`` reads (issue 13: it never uses the
ground truth, which cost ~0.05 s of CPU per generated 640x480 scene, more for BOP's visible
masks). Everything else equals the default load; a broken ground truth is not even read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_core.io import load_scene, write_sample_layout
from clutt3r_core.scene import GroundTruth, ObjectInfo
from tests.core.io.test_bop import _write_bop_scene
from tests.core.robustness._scenes import make_scene


def _same_views(a, b) -> None:
    assert (a.initial, a.post, a.name, a.root) == (b.initial, b.post, b.name, b.root)
    assert len(a.views) == len(b.views)
    for u, v in zip(a.views, b.views):
        assert (u.frame, u.name) == (v.frame, v.name)
        np.testing.assert_array_equal(u.rgb, v.rgb)
        np.testing.assert_array_equal(u.depth, v.depth)
        np.testing.assert_array_equal(u.camera.T_world_camera, v.camera.T_world_camera)
        assert (u.masks is None) == (v.masks is None)
        if u.masks is not None:
            np.testing.assert_array_equal(u.masks.masks, v.masks.masks)
            np.testing.assert_array_equal(u.masks.ids, v.masks.ids)


def _sample_scene_with_gt(root: Path) -> Path:
    sc = make_scene(2, width=64, height=48)
    maps = {v.frame: np.zeros((48, 64), np.int32) for v in sc.views}
    gt = GroundTruth((ObjectInfo(0, "box"),), maps, np.zeros((1, 3), np.float32), np.zeros(1, np.int32))
    from dataclasses import replace

    return write_sample_layout(replace(sc, ground_truth=gt), root)


def test_sample_layout_without_gt_is_the_same_scene_minus_the_gt(tmp_path):
    root = _sample_scene_with_gt(tmp_path / "s")
    full, light = load_scene(root), load_scene(root, load_gt=False)
    assert full.ground_truth is not None and light.ground_truth is None
    _same_views(full, light)
    (root / "gt" / "points.npz").write_bytes(b"not a zip")  # unread: no error
    assert load_scene(root, load_gt=False).ground_truth is None


def test_bop_without_gt_is_the_same_scene_minus_the_gt(tmp_path):
    _write_bop_scene(tmp_path / "b")
    full, light = load_scene(tmp_path / "b"), load_scene(tmp_path / "b", load_gt=False)
    assert full.ground_truth is not None and light.ground_truth is None
    _same_views(full, light)
    (tmp_path / "b" / "scene_gt.json").write_text("{broken")  # unread: no error
    assert load_scene(tmp_path / "b", load_gt=False).ground_truth is None
