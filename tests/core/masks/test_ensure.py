"""``segment(scene)`` in Python fills missing candidates like ``clutt3r segment`` does (one rule:
``masks.ensure_candidates``), records the generator, and ``save_run`` writes it; ``masks="scene"``
keeps the old refusal."""

from __future__ import annotations

import dataclasses
import functools
import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.masks import MaskProvenance, create_mask_generator, ensure_candidates
from clutt3r_core.pipeline import segment
from clutt3r_core.runs import load_run, read_run_info, save_run
from tests.core._tiny_run import tiny_scene, tiny_segmentation

pytestmark = pytest.mark.filterwarnings("ignore:Got image with third dimension")


def _without(sc, frames=None):
    return dataclasses.replace(sc, views=tuple(
        dataclasses.replace(v, masks=None) if frames is None or v.frame in frames else v for v in sc.views))


@functools.lru_cache(maxsize=1)
def _bare_segmentation():
    return segment(_without(tiny_scene()))


def test_segment_without_candidates_uses_builtin():
    sc = tiny_scene()
    seg = _bare_segmentation()
    assert seg.masks.generator == "builtin"
    assert seg.masks.generated == tuple(v.frame for v in sc.initial_views)
    assert seg.num_instances >= 1
    assert "masks" in [t.stage for t in seg.trace.timings]
    # the trace's nodes are the recorded candidates' ids
    for f, c in zip(seg.masks.frames, seg.masks.candidates):
        ids = set(seg.trace.nodes.mask_id[seg.trace.nodes.frame == f].tolist())
        assert ids and ids <= set(c.ids.tolist())


def test_segment_masks_scene_refuses_without_candidates():
    with pytest.raises(SceneError, match="no mask candidates"):
        segment(_without(tiny_scene()), masks="scene")


def test_scene_candidates_are_kept_and_recorded_as_scene():
    seg = tiny_segmentation()
    assert seg.masks.generator == "scene" and seg.masks.generated == () and seg.masks.candidates == ()
    assert "masks" not in [t.stage for t in seg.trace.timings]


def test_auto_fills_only_missing_views():
    sc = tiny_scene()
    f0 = sc.initial_views[0].frame
    part = _without(sc, {f0})
    out, prov = ensure_candidates(part, "auto")
    assert prov.generator == "builtin" and prov.generated == (f0,)
    for a, b in zip(part.initial_views, out.initial_views):
        if a.frame == f0:
            assert b.masks is not None and len(b.masks) >= 1
        else:
            assert b.masks is a.masks  # the scene's own, untouched


def test_named_generator_replaces_all_views():
    sc = tiny_scene()
    gen = create_mask_generator("builtin")
    out, prov = ensure_candidates(sc, gen)
    assert prov.generated == tuple(v.frame for v in sc.initial_views)
    same, _ = ensure_candidates(_without(sc), "builtin")
    for a, b in zip(out.initial_views, same.initial_views):  # deterministic, whatever the scene held
        assert np.array_equal(a.masks.masks, b.masks.masks)
    with pytest.raises(SceneError, match="mask generator"):
        ensure_candidates(_without(sc), 3)


def test_save_run_writes_generated_candidates_and_load_run_reads_generator(tmp_path):
    seg = _bare_segmentation()
    run = tmp_path / "run"
    save_run(seg, run)
    d = json.loads((run / "run.json").read_text())
    assert d["masks"] == {"generator": "builtin", "folder": "instance_masks", "generated": list(seg.masks.generated)}
    n = sum(len(c) for c in seg.masks.candidates)
    assert len(list((run / "instance_masks").glob("mask_*.png"))) == n
    back = load_run(run)
    assert back.masks.generator == "builtin" and back.masks.generated == seg.masks.generated
    # the same folder re-used for a run on the scene's own candidates: no stale generated masks
    save_run(tiny_segmentation(), run)
    assert not (run / "instance_masks").exists()
    assert read_run_info(run).masks.generator == "scene"


def test_bad_masks_entry_names_run_json(tmp_path):
    run = tmp_path / "run"
    save_run(tiny_segmentation(), run)
    d = json.loads((run / "run.json").read_text())
    d["masks"] = {"generator": 5}
    (run / "run.json").write_text(json.dumps(d))
    with pytest.raises(SceneFileError, match="run.json"):
        read_run_info(run)


def test_provenance_checks():
    with pytest.raises(SceneError):
        MaskProvenance(generator="scene", generated=(1,))
    with pytest.raises(SceneError):
        MaskProvenance(generator="builtin", frames=(0,), candidates=())
    assert MaskProvenance.from_json(MaskProvenance(generator="x", generated=(3,)).to_json()).generated == (3,)


def test_missing_depth_is_reported_before_generation():
    sc = _without(tiny_scene())
    v = sc.initial_views[0]
    no_depth = dataclasses.replace(sc, views=tuple(dataclasses.replace(x, depth=None) if x is v else x for x in sc.views))
    with pytest.raises(SceneError, match="no depth"):
        segment(no_depth)


class _OneMask:
    """A cheap generator: one full-image candidate (the rule under test, not the generator)."""

    name = "one"

    def generate(self, view):
        from clutt3r_core.scene import MaskCandidates

        h, w = view.camera.height, view.camera.width
        return MaskCandidates(np.ones((1, h, w), bool), np.array([1]))


@settings(max_examples=20, deadline=None)
@given(st.sets(st.integers(0, 2)))
def test_auto_generates_exactly_the_missing_views(missing_idx):
    from unittest import mock

    import clutt3r_core.masks as masks_mod

    sc = tiny_scene()
    frames = [v.frame for v in sc.initial_views]
    missing = {frames[i] for i in missing_idx if i < len(frames)}
    part = _without(sc, missing)
    with mock.patch.object(masks_mod, "create_mask_generator", lambda name="builtin", **kw: _OneMask()):
        out, prov = ensure_candidates(part, "auto")
    assert set(prov.generated) == missing
    assert prov.generator == ("scene" if not missing else "one")
    for a, b in zip(part.initial_views, out.initial_views):
        assert b.masks is not None
        assert (b.masks is a.masks) == (a.frame not in missing)
    post = [i for i in range(len(part.views)) if i not in part.initial]
    assert all(out.views[i] is part.views[i] for i in post)  # post-interaction views untouched
