"""The light embedder and the trees run on a second thread beside the fusion (issue 13): the
same results as running them in turn, the same stage list, and their errors still surface."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest

from clutt3r_core.embeddings import AppearanceEmbedder
from clutt3r_core.pipeline import segment
from tests.core.robustness._scenes import make_scene


@dataclass(frozen=True)
class InTurn:
    """The appearance embedder without ``beside_fusion``: the pipeline calls it in turn."""

    inner: AppearanceEmbedder = AppearanceEmbedder()
    name: str = "appearance-hsv"
    accepts_candidates: bool = True

    @property
    def dim(self) -> int:
        return self.inner.dim

    def embed_masks(self, rgb, masks):
        return self.inner.embed_masks(rgb, masks)


@dataclass(frozen=True)
class Broken(AppearanceEmbedder):
    def embed_masks(self, rgb, masks):
        raise RuntimeError("embedder failed")


@pytest.fixture(scope="module")
def scene():
    return make_scene(3, width=160, height=120)


def test_beside_fusion_gives_what_running_in_turn_gives(scene):
    assert AppearanceEmbedder.beside_fusion and not hasattr(InTurn(), "beside_fusion")
    a, b = segment(scene, embedder=AppearanceEmbedder()), segment(scene, embedder=InTurn())
    assert a.num_instances > 0
    np.testing.assert_array_equal(a.instance, b.instance)
    np.testing.assert_array_equal(a.scores, b.scores)
    np.testing.assert_array_equal(a.trace.embeddings, b.trace.embeddings)
    np.testing.assert_array_equal(a.trace.occupancy, b.trace.occupancy)
    for f in ("frame", "view", "mask_id", "parent", "is_leaf", "background"):
        np.testing.assert_array_equal(getattr(a.trace.nodes, f), getattr(b.trace.nodes, f))
    assert a.trace.grouping.groups == b.trace.grouping.groups
    stages = [t.stage for t in a.trace.timings]
    assert stages == [t.stage for t in b.trace.timings]
    assert stages.index("pointcloud") < stages.index("trees") < stages.index("occupancy") < stages.index("embeddings")
    assert all(t.seconds >= 0 for t in a.trace.timings)


def test_an_error_on_the_second_thread_surfaces(scene):
    with pytest.raises(RuntimeError, match="embedder failed"):
        segment(scene, embedder=Broken())
