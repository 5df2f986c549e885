"""The query's scene after an update has the grasp's normals (session 9, ``scene_after.post_eyes``):
an added instance's normals face the post view's camera whichever command asks, not +z for the query."""

from __future__ import annotations

import numpy as np

from tests.core.query._fake import FakeGrounder
from tests.core.update.test_scene_after import chain, run_copy  # noqa: F401 (fixtures)


def test_query_and_grasp_orient_the_added_instance_alike(run_copy, chain):  # noqa: F811
    from clutt3r_core.grasping.request import scene_now
    from clutt3r_core.query import RunQuery
    from clutt3r_core.update.scene_after import scene_after

    k = chain[-1]  # the added instance
    rq = RunQuery.open(run_copy, grounder=FakeGrounder())
    grasp = scene_now(run_copy, None)
    sel = grasp.instance == k
    assert sel.any() and rq.scene.step == grasp.step == 2
    np.testing.assert_array_equal(rq.scene.normals, grasp.normals)
    plus_z = scene_after(run_copy)  # what the query used before: +z
    assert not np.array_equal(plus_z.normals[sel], grasp.normals[sel])  # the camera matters to the test
