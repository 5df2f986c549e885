"""Status rules for removed objects reported static and static objects flagged (issue 10,
session 6; docs/update.md "Session 6: false static / missed removals"):

- with depth, ``ChangeConfig.presence_above_support``: a thin object grasped off the table
  leaves the table within ``presence_depth_tol`` of its stored surface; the presence test of
  ``unfitted_presence`` must not take the table for the object;
- without depth, ``ChangeConfig.photo_unjudged_rules``: an instance the stored scene itself
  hides from the new camera is ``occluded`` (not ``removed``), and one whose few informative
  points agree is ``static`` although its mask was dropped.

Tiny scenes: ``_scenes.two_boxes_on_a_table`` plus, where needed, a thin box or a hidden one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from clutt3r_core.scene import MaskCandidates, View
from clutt3r_core.update.types import ChangeConfig, UpdateConfig
from clutt3r_core.update.update import UpdateDetails, update_scene

from ._scenes import box_points, camera, render_view, state_of, two_boxes_on_a_table
from .test_depth import CAM, FAST
from .test_photo import FAST as FAST_RGB
from .test_photo import NEW_CAM


def _with(extra_pts, extra_cols, k: int):
    pts, cols, inst = two_boxes_on_a_table()
    return (np.concatenate([pts, extra_pts]), np.concatenate([cols, extra_cols]),
            np.concatenate([inst, np.full(len(extra_pts), k, np.int32)]))


# --- with depth: a thin object grasped off the table -------------------------------------

def _thin_scene(height: float):
    """Two boxes on the table and a thin box (instance 2, 8 x 8 cm, ``height`` m) in front."""
    tp, tc = box_points((0.0, -0.07, height / 2), (0.08, 0.08, height),
                        [(30, 150, 60), (30, 140, 60), (40, 160, 70), (20, 130, 50), (50, 180, 80)])
    return _with(tp, tc, 2)


@pytest.mark.parametrize("height", [0.010, 0.014])
def test_a_thin_grasped_object_is_removed_not_taken_for_the_table(height):
    pts, cols, inst = _thin_scene(height)
    st = state_of(pts, cols, inst)
    keep = inst != 2
    v = render_view(pts[keep], cols[keep], inst[keep], camera(**CAM), frame=8)  # the table under it shows
    d = UpdateDetails()
    off = update_scene(st, v, replace(FAST, change=replace(FAST.change, presence_above_support=False)), details=d)
    assert 2 in d.depth.moved and 2 not in d.depth.fits
    assert off.record(2).status == "static" and off.record(2).match == "present-depth"  # the failure
    res = update_scene(st, v, FAST)
    assert res.record(2).status == "removed" and res.record(2).match != "present-depth"
    assert [res.record(k).status for k in (0, 1)] == ["static", "static"]


def test_a_thin_object_left_in_place_stays_static():
    pts, cols, inst = _thin_scene(0.012)
    st = state_of(pts, cols, inst)
    res = update_scene(st, render_view(pts, cols, inst, camera(**CAM), frame=8), FAST)
    assert [r.status for r in res.instances] == ["static"] * 3


# --- without depth: instances the photometric test cannot judge --------------------------

def _rgb_view(pts, cols, inst, drop: tuple[int, ...] = ()) -> View:
    v = render_view(pts, cols, inst, camera(**NEW_CAM), frame=8, with_depth=False)
    keep = ~np.isin(v.masks.ids, [k + 1 for k in drop])
    return replace(v, masks=MaskCandidates(v.masks.masks[keep], v.masks.ids[keep]))


def test_an_instance_the_stored_table_hides_is_occluded_not_removed():
    # a box under the table top (a reconstruction ghost below the surface): the new camera
    # cannot see it; its splats alone (rule 5's instance-only z-buffer) would look visible
    gp, gc = box_points((0.0, -0.06, -0.03), (0.05, 0.05, 0.02),
                        [(200, 30, 200), (190, 30, 190), (210, 40, 210), (180, 20, 180), (220, 60, 220)])
    pts, cols, inst = _with(gp, gc, 2)
    st = state_of(pts, cols, inst)
    v = _rgb_view(pts, cols, inst)
    d = UpdateDetails()
    res = update_scene(st, v, FAST_RGB, details=d)
    assert d.photo_verdict.get(2) == "hidden"
    assert res.record(2).status == "occluded" and res.record(2).match == "hidden-background"
    assert [res.record(k).status for k in (0, 1)] == ["static", "static"]
    off = replace(FAST_RGB, change=replace(FAST_RGB.change, photo_unjudged_rules=False))
    assert update_scene(st, v, off).record(2).status == "removed"  # the flag the rule removes


def _table_coloured_box():
    """Box 1 painted like the table except its dark stripes: under photo_min_informative of its
    visible points are informative, but more than photo_min_points of them."""
    pts, cols, inst = two_boxes_on_a_table()
    cols = cols.copy()
    b1 = inst == 1
    dark = b1 & (cols.max(axis=1) < 80)  # box_points' stripes (0.3 x the face colour)
    cols[b1] = (115, 112, 105)
    cols[dark] = (30, 30, 30)
    return pts, cols, inst


def test_a_static_object_with_few_informative_points_whose_mask_was_dropped_stays_static():
    pts, cols, inst = _table_coloured_box()
    st = state_of(pts, cols, inst)
    v = _rgb_view(pts, cols, inst, drop=(1,))
    d = UpdateDetails()
    res = update_scene(st, v, FAST_RGB, details=d)
    pc, cc = d.photo, FAST_RGB.change
    i = pc.index(1)
    assert cc.photo_min_points <= pc.informative[i] < cc.photo_min_informative * pc.visible[i]  # unjudged
    assert d.photo_verdict.get(1) == "agree"
    assert res.record(1).status == "static" and res.record(1).match == "present-colour"
    assert res.record(0).status == "static"
    off = replace(FAST_RGB, change=replace(FAST_RGB.change, photo_unjudged_rules=False))
    assert update_scene(st, v, off).record(1).status == "removed"  # the flag the rule removes


def test_the_same_object_grasped_is_still_removed():
    pts, cols, inst = _table_coloured_box()
    st = state_of(pts, cols, inst)
    keep = inst != 1
    d = UpdateDetails()
    res = update_scene(st, _rgb_view(pts[keep], cols[keep], inst[keep]), FAST_RGB, details=d)
    assert d.photo_verdict.get(1) != "agree"
    assert res.record(1).status == "removed" and res.record(0).status == "static"


def test_the_new_field_is_a_flag():
    assert ChangeConfig().photo_unjudged_rules and ChangeConfig().presence_above_support
    assert not UpdateConfig(change=ChangeConfig(photo_unjudged_rules=False)).change.photo_unjudged_rules
