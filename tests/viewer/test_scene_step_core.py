"""The viewer's Grasps tab plans on the request ``clutt3r grasp`` plans on: after each update of a
chain, ``scene_step.scene_grasp_request`` (built from the viewer's ``UpdateFrame``s) equals the
core's ``grasping.request.request_from_run`` (built from the run's saved states,
``update.scene_after``) point for point, normal for normal, including the added instance's PCA
normals, oriented towards the camera of the post view that added it and moved by a later update."""

from __future__ import annotations

import shutil

import numpy as np


def test_the_grasps_tab_plans_on_the_commands_request(tiny_run_dir, tiny_seg, tiny_scene, tmp_path):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import scene_grasp_request
    from tests.viewer._update_chain import build_chain

    v = tiny_scene.initial_views[0]
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k = build_chain(tiny_seg, run, frame=int(v.frame))  # update 1's post view is in the scene: a camera to face
    d = load_viewer_data(run)
    assert d.updates[0].camera is not None
    for step in (1, 2):  # the added instance as added, then pushed by update 2
        for i in (0, k):
            got = scene_grasp_request(d, step, i)
            want, _, _ = request_from_run(run, i, scene=tiny_run_dir.parent / "scene", step=step)
            assert got.instance == want.instance == i and got.views == want.views == ()
            np.testing.assert_array_equal(got.points, want.points)
            np.testing.assert_array_equal(got.normals, want.normals)
            np.testing.assert_array_equal(got.target, want.target)
            assert got.voxel_size == want.voxel_size and got.target.any()
