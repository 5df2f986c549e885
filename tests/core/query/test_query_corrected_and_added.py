"""A query after an update on a CORRECTED chain that also ADDED an instance: both kinds of rows
are there at once (``RunQuery._after_updates``): the split-off id keeps its source's evidence
(``SceneAfter.run_share``) and the added instance is described from its mask in the post view."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from clutt3r_core.annotations import Split
from clutt3r_core.runs import save_run
from tests.core._tiny_run import tiny_scene, tiny_segmentation
from tests.core.update.test_corrections_update import FAST, _edit, _largest


def test_a_corrected_chain_with_an_added_instance_keeps_the_corrected_rows(tmp_path):
    from clutt3r_core.query import RunQuery
    from clutt3r_core.synth import write_synth_scene
    from clutt3r_core.update.newobj import next_instance_id
    from clutt3r_core.update.state import apply_update, save_state, state_from_run
    from clutt3r_core.update.types import InstanceUpdate, NewInstance, NewMask
    from clutt3r_core.update.update import update_scene
    from tests.core.query._fake import fake_ground_registered

    seg, scene = tiny_segmentation(), tiny_scene()
    run = save_run(seg, tmp_path / "run", scene_root=write_synth_scene(scene, tmp_path / "scene", contact_sheet=False))
    (a,) = _largest(seg, 1)
    pts = np.flatnonzero(seg.instance == a)
    _edit(run, seg, Split(points=tuple(pts[seg.points[pts, 0] < np.median(seg.points[pts, 0])].tolist()), source=a))
    k = seg.num_instances  # the split-off id
    st = state_from_run(run)
    view = scene.initial_views[0]
    res = update_scene(st, view, FAST)
    new = next_instance_id(st)
    mask = int(view.masks.ids[0])  # described from this mask of the post view
    p = seg.points[:20] + np.float32(0.3)
    res = replace(res, instances=res.instances + (InstanceUpdate(new, "new", None, 0.9, None, mask, "new-depth"),),
                  new_masks=(NewMask(mask, 100, new),),
                  added=(NewInstance(new, mask, p, np.full((20, 3), 200, np.uint8), None),),
                  change_masks=np.concatenate([res.change_masks, np.zeros_like(res.change_masks[:1])]))
    save_state(apply_update(st, res), run / "updates" / f"01_frame_{view.frame:06d}", res)
    with fake_ground_registered():
        rq = RunQuery.open(run, backend="fake-ground")
        r = rq.query("orange")
    assert new in rq.described and new in r.ranking and k in r.ranking
    e = rq.instances
    np.testing.assert_allclose(e.colors[k], e.colors[a], atol=1e-6)  # the split part: its source's, as without adds
    assert e.n_views[k] == e.n_views[a] > 0
