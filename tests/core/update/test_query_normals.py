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


def test_grasp_by_query_plans_in_the_querys_scene(run_copy, chain, monkeypatch, capsys):  # noqa: F811
    """``clutt3r grasp QUERY`` plans in the scene the query ranked (built once: the query's
    ``RunQuery.scene``), with the grasps ``--instance`` of its answer plans."""
    import json

    import clutt3r_core.query as cq
    import clutt3r_core.update.scene_after as sa_mod
    from clutt3r_core.commands.grasp import grasp_command

    k = chain[-1]  # the added instance: the orange object's mask describes it
    monkeypatch.setattr(cq, "create_grounder", lambda name=None, **kw: FakeGrounder())
    built = []
    real = sa_mod.scene_after
    monkeypatch.setattr(sa_mod, "scene_after", lambda *a, **kw: built.append(1) or real(*a, **kw))
    grasp_command(run_copy, "orange", json=True, top=3)
    by_query = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert by_query["target"] == k and by_query["step"] == 2 and by_query["grasps"]
    assert len(built) == 1  # the query's scene is the one planned in
    grasp_command(run_copy, instance=k, json=True, top=3)
    by_id = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert by_query["grasps"] == by_id["grasps"]
