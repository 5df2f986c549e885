"""The Grasps tab after an update plans on the instance's points before the contact rule, through the
core's path (session 9): ``scene_step.scene_grasp_request`` is ``clutt3r grasp --step``'s request
(``grasping.request.request_from_run``) point for point on a noisy-depth run (where the two
labellings differ), and Export records the correction log state the chain was computed from, as
``clutt3r grasp --step 1`` writes it. Driven without a browser against a real viser server."""

from __future__ import annotations

import json
import threading
from types import SimpleNamespace

import numpy as np

from clutt3r_core.annotations import Annotations, Merge
from tests.core.update.test_scene_after_geometry import _chain, _roles, base, run  # noqa: F401  (fixtures)
from tests.viewer.conftest import free_port


def test_the_grasps_tab_after_an_update_plans_the_pre_contact_extent(run, base):  # noqa: F811
    import viser

    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_core.update.state import load_state
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.panels.grasps import GraspsPanel
    from clutt3r_viewer.scene_step import scene_grasp_request, shown_scene
    from clutt3r_viewer.state import SessionState

    _, seg, pre, cleared = base
    static, moved, removed = _roles(cleared)
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=removed, other=moved))  # a corrected chain: I{moved} is part of I{removed}
    from clutt3r_core.update.run_labels import step_zero_labels

    z = step_zero_labels(seg, run)  # the targets before the update: pre-contact, the merge's both parts
    _, T = _chain(run, moved=removed)  # the merged instance is pushed, the other stays
    d = load_viewer_data(run)
    assert len(d.updates) == 1
    for k, n in ((static, z.target(static).sum()), (removed, z.target(removed).sum())):
        got = scene_grasp_request(d, 1, k)
        want = request_from_run(run, k, step=1)[0]
        np.testing.assert_array_equal(got.points, want.points)
        np.testing.assert_array_equal(got.normals, want.normals)
        np.testing.assert_array_equal(got.target, want.target)
        assert got.target.sum() == n  # the cleared points are in (of both merged parts)
    server = viser.ViserServer(host="127.0.0.1", port=free_port(), verbose=False)
    notes: list[str] = []
    try:
        with Annotations.open(run, segmentation=seg, author="test") as ann:
            s = SimpleNamespace(client=server, lock=threading.RLock(), state=SessionState(),
                                app=SimpleNamespace(data=d, annotations=ann),
                                notify=lambda title, body: notes.append(body), scene_step=lambda: 1,
                                scene=lambda: shown_scene(d, 1, np.arange(len(seg.points))))
            p = GraspsPanel()
            p.build(s)
            p.plan_for(s, static)
            assert f"({int(z.target(static).sum())} target points)" in p.summary.content, p.summary.content
            p._export(s)
        doc = json.loads((run / "grasps.json").read_text())
        src = load_state(run / "updates" / "01_frame_000008").labels
        assert doc["step"] == 1 and doc["target"] == static and doc["corrections"] == src.to_json()
    finally:
        server.stop()


def _older_chain(run, seg, moved, contact_rows: bool):  # noqa: F811
    """One saved update of ``run`` (``moved`` displaced) as an older version wrote it: no "labels"
    record in state.json, and (``contact_rows``) the run rows labelled by the contact rule."""
    from dataclasses import replace

    from clutt3r_core.update.run_labels import fused_count
    from clutt3r_core.update.state import load_state, save_state

    _chain(run, moved=moved)
    d = run / "updates" / "01_frame_000008"
    if contact_rows:
        s1 = load_state(d)
        old = np.array(s1.instance)
        old[:fused_count(seg)] = seg.instance[:fused_count(seg)]  # nothing removed: the rows are the fused points
        save_state(replace(s1, instance=old), d)
    doc = json.loads((d / "state.json").read_text())
    doc.pop("labels", None)
    (d / "state.json").write_text(json.dumps(doc))


import pytest  # noqa: E402


@pytest.mark.parametrize("contact_rows", [True, False])
def test_the_viewer_shows_the_commands_scene_of_an_older_chain(run, base, contact_rows):  # noqa: F811
    """A chain whose state.json has no "labels" record (written before session 7): the viewer's scene
    after the update is ``clutt3r grasp --step 1``'s point for point, whether the state holds the
    contact rule's labels (the scene it always was, one labelling) or the labels before it (review 8:
    the viewer skipped the core's check, 1119 of 113 511 points of /tmp/helperH/r_on differed)."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_core.update.scene_after import chain_inputs, scene_after
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import scene_after_of, scene_grasp_request

    _, seg, pre, cleared = base
    static, moved, _ = _roles(cleared)
    _older_chain(run, seg, moved, contact_rows)
    inp = chain_inputs(run, 1, seg=seg)
    assert (inp.geometry is inp.instance) == contact_rows  # the core's decision: the test tells both cases
    d = load_viewer_data(run, images=False)
    assert d.updates[0].labels is None
    v, c = scene_after_of(d, 1), scene_after(run, 1, seg=seg)
    np.testing.assert_array_equal(v.run_points, c.run_points)
    np.testing.assert_array_equal(v.gone, c.gone)
    np.testing.assert_array_equal(v.run_geometry, c.run_geometry)
    np.testing.assert_array_equal(v.points, c.points)
    for k in (static, moved):
        np.testing.assert_array_equal(scene_grasp_request(d, 1, k).target, c.grasp_target(k))


def test_the_viewer_names_the_id_a_merged_one_joined_after_an_update(run, base):  # noqa: F811
    """The Grasps tab after an update refuses a merged id with the commands' reason (review 13)."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_core.errors import SceneError
    from clutt3r_core.grasping.request import request_from_run
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import scene_grasp_request

    _, seg, pre, cleared = base
    static, moved, removed = _roles(cleared)
    with Annotations.open(run, segmentation=seg, author="test") as ann:
        ann.apply_op(Merge(into=static, other=moved))
    _chain(run, removed=removed)
    d = load_viewer_data(run, images=False)
    with pytest.raises(SceneError, match=f"merged into I{static}") as got:
        scene_grasp_request(d, 1, moved)
    with pytest.raises(SceneError) as want:
        request_from_run(run, moved, step=1)
    assert str(got.value) == str(want.value)
