"""Pre/post-interaction pairs: removed object absent afterwards, displaced object moved by the recorded motion."""

from __future__ import annotations

import numpy as np

from clutt3r_core.synth.objects import load_object


def test_prepost_pair(tiny_prepost):
    res = tiny_prepost
    s, it = res.scene, res.info.interaction
    assert it is not None and len(s.post) == 1
    post = s.views[s.post[0]]
    assert post.frame == it.post_frame == 2 and post.depth is not None and post.masks is not None
    gt = s.ground_truth
    post_map = gt.instance_maps[post.frame]
    assert not (post_map == it.removed_object).any()
    assert it.removed_object != it.displaced_object
    assert all(it.removed_object not in src for src in res.info.mask_sources[post.frame])
    # recorded motion: rigid, planar-ish (yaw about z), and a real move
    M = it.T_new_old
    assert np.allclose(M[:3, :3].T @ M[:3, :3], np.eye(3), atol=1e-6)
    T0 = gt.objects[it.displaced_object].T_world_object
    assert np.allclose(M @ T0, it.T_world_object_post, atol=1e-9)
    assert np.linalg.norm(it.T_world_object_post[:2, 3] - T0[:2, 3]) > 0.02
    # pixels of the displaced object in the post view lie on its mesh at the post pose
    import open3d as o3d

    m = load_object(gt.objects[it.displaced_object].name)
    T = it.T_world_object_post
    rs = o3d.t.geometry.RaycastingScene()
    rs.add_triangles((m.vertices @ T[:3, :3].T + T[:3, 3]).astype(np.float32), m.faces.astype(np.uint32))
    p, pix = post.camera.backproject(post.depth)
    sel = post_map.reshape(-1)[pix] == it.displaced_object
    if sel.sum() > 0:
        d = rs.compute_distance(o3d.core.Tensor(p[sel].astype(np.float32))).numpy()
        assert np.median(d) < 0.002  # default depth noise is none: mm quantisation only
    # object poses in objects.json stay the initial ones
    assert np.array_equal(gt.objects[it.displaced_object].T_world_object, T0)
