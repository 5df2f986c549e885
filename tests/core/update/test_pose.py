"""The torch pose optimiser recovers known motions from a synthetic projection (Sec. III-C)."""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.registry import create_backend
from clutt3r_core.update import PoseOptimizer
from clutt3r_core.update.pose import TorchPoseOptimizer, motion_matrix
from clutt3r_core.update.project import render_labels
from clutt3r_core.update.types import LOSS_NAMES, PoseConfig, PoseProblem, StageConfig

from ._scenes import VOXEL, camera, render_view, two_box_scene, yaw_motion

# few iterations and one start: enough for these clean problems, fast in CI
FAST = PoseConfig(coarse=StageConfig(50.0, 0.5, 10.0, 40), fine=StageConfig(10.0, 2.0, 1.0, 30),
                  yaw_starts_deg=(0.0,), early_exit=False, dof="yaw")


def _problem(T: np.ndarray, depth: bool = False) -> tuple[PoseProblem, np.ndarray]:
    pts, cols, inst = two_box_scene()
    sel = inst == 0
    moved = pts.copy()
    moved[sel] = pts[sel] @ T[:3, :3].T + T[:3, 3]
    cam = camera()
    view = render_view(moved, cols, inst, cam, with_depth=depth)
    _, occ = render_labels(moved[~sel], inst[~sel], cam, VOXEL)
    pb = PoseProblem(0, pts[sel], cols[sel], cam, view.rgb, view.masks.masks[0], occ, view.depth)
    return pb, pts[sel].mean(axis=0)


def _errors(est: np.ndarray, gt: np.ndarray, c: np.ndarray) -> tuple[float, float]:
    R = est[:3, :3] @ gt[:3, :3].T
    angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))
    shift = float(np.linalg.norm(est[:3, :3] @ c + est[:3, 3] - (gt[:3, :3] @ c + gt[:3, 3])))
    return angle, shift


def test_pure_translation_is_recovered():
    c = two_box_scene()[0][:1].mean(axis=0)  # any point: the motion has no rotation
    T = yaw_motion(0.0, (0.03, -0.02, 0.0), c)
    pb, centroid = _problem(T)
    res = TorchPoseOptimizer(FAST).optimize(pb)
    angle, shift = _errors(res.T_world, T, centroid)
    assert shift < 0.005 and angle < 3.0, (shift, angle)
    assert res.iou_after > 0.9 > res.iou_before


def test_pure_yaw_is_recovered():
    _, centroid = _problem(np.eye(4))
    T = yaw_motion(30.0, (0.0, 0.0, 0.0), centroid)
    pb, _ = _problem(T)
    res = TorchPoseOptimizer(FAST).optimize(pb)
    angle, shift = _errors(res.T_world, T, centroid)
    assert angle < 3.0 and shift < 0.005, (angle, shift)


def test_se3_with_depth_recovers_a_push():
    _, centroid = _problem(np.eye(4))
    T = yaw_motion(-35.0, (0.04, 0.03, 0.0), centroid)
    pb, _ = _problem(T, depth=True)
    cfg = PoseConfig(coarse=StageConfig(50.0, 0.5, 10.0, 45), fine=StageConfig(10.0, 2.0, 1.0, 20),
                     yaw_starts_deg=(0.0, -40.0), probe_iterations=10, dof="se3")
    res = TorchPoseOptimizer(cfg).optimize(pb)
    angle, shift = _errors(res.T_world, T, centroid)
    assert shift < 0.01 and angle < 5.0, (shift, angle)


def test_every_iteration_is_recorded_and_early_exit_skips_the_fine_stage():
    _, centroid = _problem(np.eye(4))
    T = yaw_motion(0.0, (0.02, 0.0, 0.0), centroid)
    pb, _ = _problem(T)
    cfg = PoseConfig(coarse=StageConfig(50.0, 0.5, 10.0, 30), fine=StageConfig(10.0, 2.0, 1.0, 10),
                     yaw_starts_deg=(0.0,), dof="yaw", early_exit=True)
    res = TorchPoseOptimizer(cfg).optimize(pb)
    tr = res.trace
    assert res.stages == 1 and set(tr.stage.tolist()) == {0}  # IoU >= tau after the coarse stage
    assert len(tr) == 31 and tr.losses.shape == (31, len(LOSS_NAMES))
    assert np.all(np.isfinite(tr.losses)) and np.all((tr.iou >= 0) & (tr.iou <= 1))
    np.testing.assert_allclose(tr.T_world[-1], res.T_world)
    assert tr.iou[-1] >= cfg.tau_iou
    # the same problem twice gives the same result (deterministic)
    again = TorchPoseOptimizer(cfg).optimize(pb)
    np.testing.assert_allclose(again.T_world, res.T_world, atol=1e-9)


def test_registry_builds_the_optimiser():
    opt = create_backend("pose_optimizer", "torch-adam", config=FAST)
    assert isinstance(opt, PoseOptimizer) and opt.name == "torch-adam"


def test_motion_matrix_rotates_about_the_centre():
    a = np.deg2rad(90)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    c = np.array([1.0, 0.0, 0.0])
    T = motion_matrix(R, c, np.zeros(3))
    np.testing.assert_allclose(T[:3, :3] @ c + T[:3, 3], c)


def test_bad_problem_is_refused():
    pb, _ = _problem(np.eye(4))
    with pytest.raises(SceneError, match="mask must be"):
        PoseProblem(0, pb.points, pb.colors, pb.camera, pb.rgb, pb.mask[:-1], pb.occluder_depth)
    with pytest.raises(SceneError, match="dof"):
        PoseConfig(dof="xyz")


def test_a_box_tipped_on_its_side_is_recovered_from_a_tilted_start():
    from dataclasses import replace

    from scipy.spatial.transform import Rotation

    from clutt3r_core.update.pose import tilted_start

    _, c = _problem(np.eye(4))
    R = Rotation.from_rotvec([np.pi / 2, 0, 0]).as_matrix()  # on its side: 4 cm tall instead of 6
    pts = two_box_scene()[0][two_box_scene()[2] == 0].astype(np.float64)
    drop = ((pts - c) @ R.T + c)[:, 2].min() - pts[:, 2].min()  # it rests on the table again
    T = motion_matrix(R, c, np.array([0.02, 0.03, -drop]))
    pb, _ = _problem(T)
    tilt = replace(FAST, tilt_starts=True)
    T0 = tilted_start(pb, tilt)
    assert T0 is not None
    assert _errors(T0, T, c)[0] <= 16.0  # within half the 30 deg yaw step of the placements
    angle, shift = _errors(TorchPoseOptimizer(tilt).optimize(pb).T_world, T, c)
    assert angle < 5.0 and shift < 0.006, (angle, shift)
    # the yaw fit alone (the default) cannot tip it over
    angle0, _ = _errors(TorchPoseOptimizer(FAST).optimize(pb).T_world, T, c)
    assert angle0 > 45.0
