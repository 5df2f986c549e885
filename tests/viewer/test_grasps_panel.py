"""The Grasps tab against a real viser server (its scene and GUI APIs), without a browser."""

from __future__ import annotations

import threading
from types import SimpleNamespace

import numpy as np

from clutt3r_core.grasping.gripper import FRANKA
from clutt3r_viewer.panels.grasps import GraspsPanel, closing_region_segments, gripper_segments
from clutt3r_viewer.state import SessionState
from tests.viewer.conftest import free_port


def test_gripper_outline_and_closing_region_follow_the_convention():
    T = np.eye(4)
    T[:3, 3] = [1, 2, 3]
    s = gripper_segments(T, 0.06)
    np.testing.assert_allclose(s[1, 1], [1 - 0.03, 2, 3 + FRANKA.finger_z[1]], atol=1e-6)  # left fingertip
    np.testing.assert_allclose(s[0, 0], [1 - 0.03, 2, 3 + FRANKA.finger_z[0]], atol=1e-6)  # palm face
    r = closing_region_segments(T, 0.06).reshape(-1, 3) - T[:3, 3]
    np.testing.assert_allclose(r.min(0), [-0.03, -0.01, -0.02], atol=1e-6)
    np.testing.assert_allclose(r.max(0), [0.03, 0.01, 0.02], atol=1e-6)


def test_plan_select_and_export(tiny_data, tmp_path):
    import viser

    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    notes = []
    try:
        s = SimpleNamespace(client=server, lock=threading.RLock(), state=SessionState(),
                            app=SimpleNamespace(data=tiny_data, annotations=SimpleNamespace(run_dir=tmp_path)),
                            notify=lambda title, body: notes.append(body), scene_step=lambda: 0)  # the run, no update
        p = GraspsPanel()
        assert GraspsPanel.available(s.app)
        p.build(s)
        for k in range(tiny_data.seg.num_instances):  # some instances are too big for the hand
            p.plan_for(s, k)
            assert p._target == k and len(p._grasps) <= p.top.value
            assert len(p.grasp.options) == len(p._grasps) + 1
            assert ("no grasp" in p.summary.content) == (len(p._grasps) == 0)
            if len(p._grasps):
                break
        assert len(p._grasps) > 0, p.summary.content
        p.select_grasp(s, p.grasp.options[1])
        assert s.state.grasp == 0 and p.selected is not None and p.region is not None and p.contacts is not None
        p._export(s)
        from clutt3r_core.grasping import GraspSet

        assert len(GraspSet.load(tmp_path / "grasps.json")) == len(p._grasps)
        assert "wrote" in notes[-1]
    finally:
        server.stop()
