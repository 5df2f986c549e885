"""The update's embedder: stored instances re-embedded from the run's views (query cache), the
choice of ``auto``, and the name recorded in update.json / the chained state."""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.query.evidence import CACHE_NAME
from clutt3r_core.runs import save_run
from clutt3r_core.synth import write_synth_scene
from clutt3r_core.update import embed
from clutt3r_core.update.state import apply_update, load_state, save_state, state_from_run
from tests.core._tiny_run import tiny_scene, tiny_segmentation
from tests.core.query._fake import FakeGrounder


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    root = tmp_path_factory.mktemp("upd_embed")
    scene_dir = write_synth_scene(tiny_scene(), root / "scene", contact_sheet=False)
    return save_run(tiny_segmentation(), root / "run", scene_root=scene_dir)


def test_reembedding_follows_the_run_ids_and_is_cached(run_dir, tmp_path):
    st = state_from_run(run_dir)
    assert st.embedder == "appearance-hsv"
    g = FakeGrounder()
    new = embed.with_embedder(st, "fake-ground", embedder=g)
    assert new.embedder == "fake-ground" and new.embeddings.shape == (len(st.instance_ids), 3)
    np.testing.assert_allclose(np.linalg.norm(new.embeddings, axis=1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(new.points, st.points)
    assert (run_dir / CACHE_NAME).is_file() and g.calls > 0
    # the same embeddings as the multi-view instance evidence, and read from the cache next time
    g2 = FakeGrounder()
    again = embed.with_embedder(st, "fake-ground", embedder=g2)
    assert g2.calls == 0
    np.testing.assert_allclose(again.embeddings, new.embeddings, atol=2e-3)  # the cache stores float16
    # a chained state (an instance removed) takes its remaining ids' rows
    ids = st.instance_ids
    sub = apply_update(st, _removal(st, int(ids[0])))
    sub_new = embed.with_embedder(sub, "fake-ground", embedder=FakeGrounder())
    np.testing.assert_allclose(sub_new.embeddings, new.embeddings[1:], atol=2e-3)
    # saved and loaded, the state keeps the embedder's name and vectors
    back = load_state(save_state(sub_new, tmp_path / "s"))
    assert back.embedder == "fake-ground"
    np.testing.assert_array_equal(back.embeddings, sub_new.embeddings)
    assert embed.with_embedder(back, "fake-ground") is back  # already in that space


def test_auto_and_errors(run_dir, monkeypatch):
    st = state_from_run(run_dir)
    assert embed.resolve_embedder("appearance-hsv", st) == "appearance-hsv"
    assert embed.resolve_embedder("run", st) == st.embedder  # the command's default
    monkeypatch.setattr(embed, "learned_available", lambda: False)
    assert embed.resolve_embedder("auto", st) == st.embedder
    monkeypatch.setattr(embed, "learned_available", lambda: True)
    assert embed.resolve_embedder("auto", st) == embed.LEARNED
    from dataclasses import replace

    assert embed.resolve_embedder("auto", replace(st, run=None)) == st.embedder  # nothing to re-embed from

    with pytest.raises(SceneError, match="run folder"):
        embed.with_embedder(replace(st, run=None), "fake-ground", embedder=FakeGrounder())


def _removal(st, k):
    from clutt3r_core.update.types import InstanceUpdate, UpdateResult

    recs = tuple(InstanceUpdate(int(i), "removed" if int(i) == k else "static", None, None, None, -1, "")
                 for i in st.instance_ids)
    return UpdateResult(frame=5, instances=recs, new_masks=(), change_masks=np.zeros((len(recs), 2, 2), bool),
                        projected=np.full((2, 2), -1, np.int32), time_s=0.0)
