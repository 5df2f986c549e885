"""The builtin generator on an analytic tabletop: objects found, a containment hierarchy, the
support left out, determinism, clear errors."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.masks import create_mask_generator, fill_masks, scene_has_masks
from clutt3r_core.masks.builtin import BuiltinMaskConfig, builtin_candidates
from clutt3r_core.masks.quality import mask_iou_matrix, view_quality
from clutt3r_core.scene import Scene
from tests.core.masks._box_scene import box_view

pytestmark = pytest.mark.filterwarnings("ignore:Got image with third dimension")


def _nested_or_disjoint(masks: np.ndarray) -> bool:
    m = masks.reshape(len(masks), -1).astype(np.float32)
    inter = m @ m.T
    area = m.sum(1)
    nested = (inter == area[:, None]) | (inter == area[None, :])
    return bool(np.all(nested | (inter == 0)))


def test_objects_parent_and_support():
    """Default config: the separate box gets its own candidate, the two touching boxes (coplanar
    front faces, only colour tells them apart) one under-segmented cluster candidate (colour is
    weighted low on purpose, docs/masks.md), and the support plane none."""
    view, ids = box_view()
    c = builtin_candidates(view)
    gt = np.stack([ids == 2, (ids == 0) | (ids == 1)])
    assert (mask_iou_matrix(gt, c.masks).max(axis=1) >= 0.9).all()
    table = ids == -1
    assert (c.masks & table).sum() < 0.02 * c.masks.sum()  # the support plane is removed
    assert c.ids.tolist() == list(range(1, len(c) + 1))
    assert c.scores is not None and ((c.scores > 0) & (c.scores <= 1)).all()


def test_colour_split_gives_parent_with_children():
    """With colour weighted fully, the cluster is a parent and each touching box a leaf inside it."""
    view, ids = box_view()
    c = builtin_candidates(view, BuiltinMaskConfig(w_colour=1.0))
    gt = np.stack([ids == k for k in range(3)] + [(ids == 0) | (ids == 1)])
    iou = mask_iou_matrix(gt, c.masks)
    assert (iou.max(axis=1) >= 0.9).all(), iou.max(axis=1)
    q = view_quality(c, ids)
    assert q.num_parents >= 1 and q.num_leaves >= 3
    parent = c.masks[int(iou[3].argmax())]
    for k in (0, 1):  # each box's candidate lies inside the cluster's
        child = c.masks[int(iou[k].argmax())]
        assert (child & ~parent).sum() == 0


def test_hierarchy_nested_by_construction_and_deterministic():
    view, _ = box_view(eye=(-0.3, -0.35, 0.45))
    c1 = builtin_candidates(view)
    c2 = builtin_candidates(view)
    assert np.array_equal(c1.masks, c2.masks)
    assert _nested_or_disjoint(c1.masks)


@settings(max_examples=6, deadline=None)
@given(st.floats(-0.25, 0.25), st.floats(0.3, 0.5), st.floats(-0.04, 0.04))
def test_nested_or_disjoint_property(ex, ez, shift):
    boxes = (
        (np.array([-0.06 + shift, -0.04, 0.0]), np.array([0.0 + shift, 0.04, 0.08]), (180, 40, 40)),
        (np.array([0.0 + shift, -0.03, 0.0]), np.array([0.05 + shift, 0.05, 0.05]), (40, 60, 200)),
    )
    view, _ = box_view(eye=(ex, -0.4, ez), width=160, height=120, f=150.0, boxes=boxes)
    c = builtin_candidates(view)
    assert _nested_or_disjoint(c.masks)
    area = view.camera.width * view.camera.height
    assert (c.areas() >= BuiltinMaskConfig().min_area_frac * area).all()


def test_large_view_is_processed_at_work_width_and_returned_full_size():
    view, ids = box_view(width=960, height=720, f=900.0)
    c = builtin_candidates(view)
    assert c.shape == (720, 960)
    gt = np.stack([ids == 2, (ids == 0) | (ids == 1)])
    assert (mask_iou_matrix(gt, c.masks).max(axis=1) >= 0.85).all()



def test_errors():
    view, _ = box_view(width=64, height=48, f=60.0)
    with pytest.raises(SceneError, match="needs depth"):
        builtin_candidates(dataclasses.replace(view, depth=None))
    with pytest.raises(SceneError, match="levels"):
        BuiltinMaskConfig(levels=(0.5, 0.2))


def test_no_planes_no_depth_holes_all_nan():
    view, _ = box_view(width=64, height=48, f=60.0)
    empty = dataclasses.replace(view, depth=np.full((48, 64), np.nan, np.float32))
    assert len(builtin_candidates(empty)) == 0


def test_fill_masks_gives_every_initial_view_candidates():
    views = [box_view(frame=i, eye=e)[0] for i, e in enumerate([(0.05, -0.45, 0.5), (-0.35, -0.3, 0.45)])]
    sc = Scene(views=tuple(views), initial=(0, 1))
    assert not scene_has_masks(sc)
    gen = create_mask_generator("builtin")
    assert gen.name == "builtin"
    filled = fill_masks(sc, gen)
    assert scene_has_masks(filled) and all(len(v.masks) >= 2 for v in filled.initial_views)
