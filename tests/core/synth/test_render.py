"""Rendering: clean depth back-projected with the saved camera lies on the posed meshes."""

from __future__ import annotations

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutt3r_core.synth.objects import load_object
from clutt3r_core.synth.render import TABLE_STYLES, build_geometry, look_at_camera, render_view

from .conftest import tiny


def _posed_mesh_distance(scene, points):
    import open3d as o3d

    rs = o3d.t.geometry.RaycastingScene()
    for o in scene.ground_truth.objects:
        m = load_object(o.name)
        T = o.T_world_object
        rs.add_triangles((m.vertices @ T[:3, :3].T + T[:3, 3]).astype(np.float32), m.faces.astype(np.uint32))
    return rs.compute_distance(o3d.core.Tensor(points.astype(np.float32))).numpy()


@settings(max_examples=3, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 40))
def test_backprojected_depth_lands_on_meshes(seed):
    res = tiny(seed, depth_noise="none")
    s = res.scene
    gt = s.ground_truth
    n = 0
    for v in s.views:
        p, pix = v.camera.backproject(v.depth)  # the saved (mm-quantised) clean depth
        lab = gt.instance_maps[v.frame].reshape(-1)[pix]
        obj = lab >= 0
        if obj.any():
            d = _posed_mesh_distance(s, p[obj])
            assert np.quantile(d, 0.999) < 1e-3 and d.max() < 1.5e-3
            n += obj.sum()
        # background pixels lie on the table plane (z = 0) or the tray
        bg = p[~obj]
        assert np.quantile(np.abs(bg[:, 2]), 0.5) < 0.01
    assert n > 0


def test_depth_is_z_not_ray_length():
    # a single flat table seen head-on from 0.5 m: z-depth is 0.5 m everywhere
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]])
    cam = look_at_camera(np.array([0.0, 0.0001, 0.5]), np.zeros(3), K, 160, 120)
    g = build_geometry([], np.zeros((0, 4, 4)), [])
    r = render_view(g, cam, table=TABLE_STYLES[1])
    vs, us = np.mgrid[0:120, 0:160]
    d = np.stack([(us - 79.5) / 100.0, (vs - 59.5) / 100.0, np.ones_like(us, float)], -1) @ cam.T_world_camera[:3, :3].T
    expected = -cam.T_world_camera[2, 3] / d[..., 2]  # ray parameter with unit camera-z = z-depth
    assert np.allclose(r.depth, expected, atol=1e-5)
    assert np.allclose(r.depth, 0.5, atol=2e-4)  # (nearly) head-on: constant z, although corner rays are longer
    assert (r.instance == -1).all()
    assert r.rgb.std() > 1.0  # the table is patterned, not flat


def test_instance_map_matches_object_geometry():
    obj = load_object("013_apple")
    T = np.eye(4)
    T[2, 3] = obj.extent[2] / 2
    K = np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]])
    cam = look_at_camera(np.array([0.3, 0.0, 0.4]), np.array([0, 0, 0.03]), K, 160, 120)
    g = build_geometry([obj], T[None], [7])
    r = render_view(g, cam)
    assert set(np.unique(r.instance).tolist()) == {-1, 7}
    assert np.isnan(r.depth).sum() == 0
