"""The final refinement of a depth registration (ours, session 7; ``update/depth_refine.py``):
symmetric point-to-plane ICP from the registered pose. Tiny scenes: the boxes of
``_scenes.two_boxes_on_a_table``, box 0 pushed and turned."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st_
from scipy.spatial.transform import Rotation

from clutt3r_core.update.depth import _consistency, mask_points, prepare_model, register, start_rotations
from clutt3r_core.update import depth_refine
from clutt3r_core.update.depth_refine import (Refinement, flip_check, half_turn_symmetric, pose_quality,
                                              refine_registration, refined_registration)
from clutt3r_core.update.types import PoseConfig, UpdateConfig
from clutt3r_core.update.update import update_scene

from ._scenes import camera, render_view
from .test_depth import CAM, FAST
from .test_depth_regions import _pushed


def _errors(T: np.ndarray, T_true: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    """(rotation error deg, metres between the centre moved by T and by T_true)."""
    ang = np.degrees(np.arccos(np.clip((np.trace(T[:3, :3] @ T_true[:3, :3].T) - 1) / 2, -1, 1)))
    return float(ang), float(np.linalg.norm(T[:3, :3] @ c + T[:3, 3] - T_true[:3, :3] @ c - T_true[:3, 3]))


def _perturbed(T: np.ndarray, c: np.ndarray, rotvec, shift) -> np.ndarray:
    """T followed by a turn ``rotvec`` (rad) about the moved centre and a ``shift`` (m)."""
    D = np.eye(4)
    D[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    m = T[:3, :3] @ c + T[:3, 3]
    D[:3, 3] = m - D[:3, :3] @ m + np.asarray(shift)
    return D @ T


BOX0 = ((-0.06, 0.0, 0.03), (0.06, 0.04, 0.06))  # _scenes.two_box_scene's boxes: centre, size (m)
BOX1 = ((0.07, 0.03, 0.025), (0.05, 0.05, 0.05))


def _raycast(cam, boxes) -> tuple[np.ndarray, np.ndarray]:
    """Exact depth ((H, W) camera z, m; NaN: no hit) and the index of the box hit ((H, W), -1: the
    table z = 0 or nothing) of boxes (centre, size, T_world: the box moved by T) over the table:
    ray / slab intersections, not splats (splatted depth sits up to ~4 mm in front of the
    surface on inclined faces, which would hide the millimetres this refinement is about)."""
    vs, us = np.mgrid[0 : cam.height, 0 : cam.width]
    far = cam.pixels_to_world(us.ravel().astype(float), vs.ravel().astype(float), np.ones(us.size))
    o = cam.T_world_camera[:3, 3]
    d = far - o  # world ray per pixel, scaled so that the camera z of o + s d is s
    best = np.full(us.size, np.inf)
    hit = np.full(us.size, -1)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_table = -o[2] / d[:, 2]
        best = np.where(s_table > 0, s_table, np.inf)
        for i, (c, size, T) in enumerate(boxes):
            R, t = T[:3, :3], T[:3, 3]
            ol = R.T @ (o - t) - np.asarray(c)  # the ray in the box's own (unmoved, centred) frame
            dl = d @ R
            half = np.asarray(size) / 2
            lo, hi = (-half - ol) / dl, (half - ol) / dl
            s_in = np.nanmax(np.minimum(lo, hi), axis=1)
            s_out = np.nanmin(np.maximum(lo, hi), axis=1)
            ok = (s_in <= s_out) & (s_in > 0) & (s_in < best)
            best[ok], hit[ok] = s_in[ok], i
    depth = np.where(np.isfinite(best), best, np.nan).reshape(cam.height, cam.width)
    return depth, hit.reshape(cam.height, cam.width)


def _case(yaw=25.0, seed=0):
    """(camera, exact depth, box 0's scene points, its prepared model, its centre, true T)."""
    pts, cols, inst, st, c, T, moved = _pushed(yaw)
    cam = camera(**CAM)
    depth, hit = _raycast(cam, [(*BOX0, T), (*BOX1, np.eye(4))])
    scene = mask_points(cam, depth, hit == 0, max_points=250, seed=seed)
    model = prepare_model(st.points_of(0).astype(np.float64), st.colors[st.instance == 0])
    return SimpleNamespace(camera=cam, depth=depth), scene, model, c, T


@settings(max_examples=12, deadline=None)
@given(st_.floats(-1.0, 1.0), st_.floats(-1.0, 1.0), st_.floats(-1.0, 1.0), st_.floats(1.0, 5.0),
       st_.floats(-0.004, 0.004))
def test_a_pose_a_few_degrees_off_is_pulled_onto_the_observed_box(ax, ay, az, deg, dz):
    # the residual the refinement is for: a start a few degrees off, and millimetres off along
    # the top face's normal (a shift along the edge of the two faces this camera sees is not
    # observable in depth: the point-to-plane terms leave it as it is)
    v, scene, model, c, T = _case()
    axis = np.array([ax, ay, az])
    if np.linalg.norm(axis) < 1e-3:
        axis = np.array([0.0, 0.0, 1.0])
    start = _perturbed(T, c, axis / np.linalg.norm(axis) * np.deg2rad(deg), (0.0, 0.0, dz))
    ref = refine_registration(model, scene, start, v.camera, v.depth)
    r0, t0 = _errors(start, T, c)
    r1, t1 = _errors(ref.T_world, T, c)
    assert r1 < 1.0 and t1 < 0.002, (r0, t0, r1, t1)
    assert len(ref.path) == 15 and np.array_equal(ref.path[-1], ref.T_world)


def test_the_true_pose_stays_put():
    v, scene, model, c, T = _case()
    r, t = _errors(refine_registration(model, scene, T, v.camera, v.depth).T_world, T, c)
    assert r < 0.5 and t < 0.001


def test_the_registration_is_refined_and_measured_again():
    v, scene, model, c, T = _case(40.0)
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01, alternatives=2)
    start = _perturbed(reg.T_world, c, (0.0, np.deg2rad(4.0), 0.0), (0.003, 0.0, 0.0))
    worse = replace(reg, T_world=start)
    ref = refined_registration(worse, model, scene, v.camera, v.depth, 0.01)
    assert _errors(ref.T_world, T, c)[0] < _errors(start, T, c)[0] - 2.0
    # the scores are the refined pose's own (register's definitions)
    assert ref.consistency == pytest.approx(_consistency(model.points, ref.T_world, v.camera, v.depth, 0.01)[0])
    d = model.tree.query(np.ascontiguousarray((scene - ref.T_world[:3, 3]) @ ref.T_world[:3, :3]))[0]
    assert ref.fitness == pytest.approx(float((d <= 0.01).mean()))
    assert ref.score == pytest.approx(ref.fitness * ref.consistency)
    # the replay shows the ICP's iterations, then the refinement's
    assert len(ref.path) == len(reg.path) + 15 and len(ref.path_cost) == len(ref.path)
    assert np.array_equal(ref.path[-1], ref.T_world) and ref.alternatives == ()


def test_without_pairs_nothing_moves():
    # a scene far from the model (no pair within the radius): the registration comes back as it was
    v, scene, model, c, T = _case()
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01)
    far = replace(reg, T_world=_perturbed(reg.T_world, c, (0.0, 0.0, 0.0), (0.2, 0.0, 0.0)))
    assert refined_registration(far, model, scene, v.camera, v.depth, 0.01) is far
    assert len(refine_registration(model, scene, far.T_world, v.camera, v.depth).path) == 0


def test_update_scene_refines_the_displaced_pose_and_can_turn_it_off():
    pts, cols, inst, st, c, T, moved = _pushed(25.0)
    v = render_view(moved, cols, inst, camera(**CAM), frame=8)
    on = update_scene(st, v, FAST)
    off = update_scene(st, v, UpdateConfig(change=FAST.change, pose=replace(FAST.pose, registration_refine_iterations=0)))
    a, b = on.record(0), off.record(0)
    assert a.status == b.status == "displaced" and on.record(1).status == off.record(1).status == "static"
    assert len(a.pose.trace) == len(b.pose.trace) + PoseConfig().registration_refine_iterations
    ra, ta = _errors(a.T_world, T, c)
    rb, tb = _errors(b.T_world, T, c)
    # measured: 2.08 -> 0.52 deg; both ~4.1 mm off, because this view's depth is splatted (it
    # sits up to ~4 mm in front of inclined faces; _raycast's exact depth is used above)
    assert ra < 1.0 and ra < rb - 1.0 and ta < tb + 0.0005, (ra, ta, rb, tb)


def _coloured_case(yaw=25.0):
    """_case with the view's colours (splatted RGB; the depth stays exact)."""
    pts, cols, inst, st, c, T, moved = _pushed(yaw)
    v, scene, model, c, T = _case(yaw)
    rgb = render_view(moved, cols, inst, v.camera, frame=8).rgb
    return v, rgb, scene, model, c, T


def _half_turn(T, c):
    """T preceded by a half turn about the vertical axis through the box's (old) centre: box 0
    (6 x 4 x 6 cm, axis-aligned) maps onto itself, its +y and -y faces' colours swap."""
    S = np.eye(4)
    S[:3, :3] = np.diag([-1.0, -1.0, 1.0])
    S[:3, 3] = c - S[:3, :3] @ c
    return T @ S


def test_a_half_turn_of_a_printed_box_is_turned_back_by_its_colours():
    v, rgb, scene, model, c, T = _coloured_case()
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01)
    wrong = replace(reg, T_world=_half_turn(T, c), alternatives=())
    assert _errors(wrong.T_world, T, c)[0] > 179.0
    got, flipped = flip_check(wrong, model, scene, v.camera, v.depth, rgb, 0.01)
    assert flipped and _errors(got.T_world, T, c)[0] < 1.0
    # the geometry alone cannot tell: both poses fit the depth alike
    assert abs(got.score - refined_registration(wrong, model, scene, v.camera, v.depth, 0.01).score) < 0.05
    # the replay keeps the path that led to the half turn
    assert len(got.path) == len(reg.path) + 15 and np.array_equal(got.path[-1], got.T_world)


def test_the_right_side_stays_and_no_colours_change_nothing():
    v, rgb, scene, model, c, T = _coloured_case()
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01)
    right = refined_registration(replace(reg, T_world=T), model, scene, v.camera, v.depth, 0.01)
    got, flipped = flip_check(right, model, scene, v.camera, v.depth, rgb, 0.01)
    assert not flipped and got is right
    wrong = replace(reg, T_world=_half_turn(T, c))
    assert flip_check(wrong, model, scene, v.camera, v.depth, None, 0.01) == (wrong, False)
    bare = prepare_model(model.points)  # a model without colours
    assert flip_check(wrong, bare, scene, v.camera, v.depth, rgb, 0.01) == (wrong, False)


@pytest.mark.parametrize("kw", [dict(registration_refine_iterations=-1), dict(registration_refine_radius=(0.005, 0.01)),
                                dict(registration_refine_radius=(0.01, 0.0)),
                                dict(registration_refine_keep=(-1.0, 0.01)),
                                dict(registration_flip_symmetric=(1.0, -0.05))])
def test_a_bad_refinement_setting_is_refused_naming_it(kw):
    from clutt3r_core.errors import SceneError

    with pytest.raises(SceneError, match=next(iter(kw))):
        PoseConfig(**kw)


# -- session 7, H6: the keep test and the symmetric half turns (docs/update.md "Session 7:
# refinement regressions")


def test_the_keep_test_returns_the_registration_when_the_refined_pose_is_worse(monkeypatch):
    # a refinement that lands 15 deg off (intermediate_700's can tilted 2.3 -> 14 deg): the free
    # space and the colours the refinement does not use say so, and the registered pose is kept
    # (measured on this fixture: a few degrees or -5 mm along z are NOT told apart, its stored
    # points come from splatted views: the criterion is a coarse guard, not a fine objective)
    v, rgb, scene, model, c, T = _coloured_case()
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01)
    good = replace(reg, T_world=T, alternatives=())
    off = _perturbed(T, c, (0.0, 0.0, np.deg2rad(15.0)), (0.0, 0.0, 0.0))
    monkeypatch.setattr(depth_refine, "refine_registration",
                        lambda *a, **k: Refinement(off, off[None], np.zeros(1)))
    q_good, q_off = (pose_quality(model, X, v.camera, v.depth, 0.01, rgb) for X in (T, off))
    assert q_off < q_good - 0.01, (q_good, q_off)
    assert refined_registration(good, model, scene, v.camera, v.depth, 0.01, rgb=rgb, keep=(2.0, 0.01)) is good
    # without the test (or with a margin wider than the loss) the refinement's pose is taken
    assert np.array_equal(refined_registration(good, model, scene, v.camera, v.depth, 0.01).T_world, off)
    wide = refined_registration(good, model, scene, v.camera, v.depth, 0.01, rgb=rgb, keep=(2.0, q_good - q_off + 0.01))
    assert np.array_equal(wide.T_world, off)


@settings(max_examples=8, deadline=None)
@given(st_.floats(-1.0, 1.0), st_.floats(-1.0, 1.0), st_.floats(0.0, 8.0), st_.floats(-0.004, 0.004))
def test_a_kept_refinement_is_never_worse_than_the_margin_by_the_keep_criterion(ax, ay, deg, dx):
    v, rgb, scene, model, c, T = _coloured_case()
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01)
    axis = np.array([ax, ay, 1.0])
    start = replace(reg, T_world=_perturbed(T, c, axis / np.linalg.norm(axis) * np.deg2rad(deg), (dx, 0.0, 0.0)),
                    alternatives=())
    got = refined_registration(start, model, scene, v.camera, v.depth, 0.01, rgb=rgb, keep=(2.0, 0.01))
    q0 = pose_quality(model, start.T_world, v.camera, v.depth, 0.01, rgb)
    assert got is start or pose_quality(model, got.T_world, v.camera, v.depth, 0.01, rgb) >= q0 - 0.01


def test_half_turn_symmetry_of_the_stored_points():
    v, scene, model, c, T = _case()
    cc = model.points.mean(axis=0)

    def turn(axis):
        S = np.eye(4)
        S[:3, :3] = Rotation.from_rotvec(np.pi * np.asarray(axis, float)).as_matrix()
        S[:3, 3] = cc - S[:3, :3] @ cc
        return S

    # box 0's stored points (its top and its sides) map onto themselves under the vertical turn
    assert half_turn_symmetric(model, turn((0, 0, 1)))
    # a quarter turn of a 6 x 4 cm footprint, or a half turn that moves the top to the bottom, does not
    S = np.eye(4)
    S[:3, :3] = Rotation.from_rotvec((0, 0, np.pi / 2)).as_matrix()
    S[:3, 3] = cc - S[:3, :3] @ cc
    assert not half_turn_symmetric(model, S)
    # a partial cloud (one half of the box's stored points) is not symmetric under that turn
    half = prepare_model(model.points[model.points[:, 0] < cc[0]])
    assert not half_turn_symmetric(half, turn((0, 0, 1)))


def test_a_symmetric_half_turn_needs_the_larger_colour_margin():
    # the printed box's half turn maps its stored points onto themselves and wins by ~0.13 of
    # colour error: taken with the default 0.05, not with a margin above its gain
    v, rgb, scene, model, c, T = _coloured_case()
    reg = register(model, scene, v.camera, v.depth, starts=start_rotations(30.0), tol=0.01)
    wrong = replace(reg, T_world=_half_turn(T, c), alternatives=())
    assert flip_check(wrong, model, scene, v.camera, v.depth, rgb, 0.01, symmetric=(1.0, 0.05))[1]
    assert flip_check(wrong, model, scene, v.camera, v.depth, rgb, 0.01, symmetric=(1.0, 0.2)) == (wrong, False)
    # not symmetric by a ratio of 0 (no turn maps the points within zero spacing): the plain margin
    assert flip_check(wrong, model, scene, v.camera, v.depth, rgb, 0.01, symmetric=(0.0, 0.2))[1]
