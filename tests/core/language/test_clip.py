"""Wiring of the CLIP backends with tiny randomly initialised models built here.

These test the plumbing (paths, preprocessing, shapes, unit norms, the registry, the query
path in shared-space mode), NOT retrieval quality: the models are random."""

from __future__ import annotations

import json
import sys
import types

import numpy as np
import pytest

from clutt3r_core.errors import Clutt3rError, MissingDependencyError
from clutt3r_core.language.base import Grounder
from clutt3r_core.registry import create_backend

torch = pytest.importorskip("torch")
pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


class _Img(torch.nn.Module):
    def __init__(self, d: int = 16) -> None:
        super().__init__()
        self.conv = torch.nn.Conv2d(3, 8, 4, stride=4)
        self.fc = torch.nn.Linear(8, d)

    def forward(self, x):
        return self.fc(self.conv(x).mean(dim=(2, 3)))


class _Txt(torch.nn.Module):
    def __init__(self, vocab: int = 64, d: int = 16) -> None:
        super().__init__()
        self.emb = torch.nn.Embedding(vocab, d)

    def forward(self, ids):
        return self.emb(ids).mean(dim=1)


def _tokenizer_json(path):
    from tokenizers import Tokenizer, models, pre_tokenizers

    vocab = {w: i for i, w in enumerate(["<|endoftext|>", "[UNK]", "a", "red", "mug", "banana", "the", "yellow"])}
    tok = Tokenizer(models.WordLevel(vocab, unk_token="[UNK]"))
    tok.pre_tokenizer = pre_tokenizers.Whitespace()
    tok.save(str(path))
    return path


@pytest.fixture(scope="module")
def onnx_pair(tmp_path_factory):
    pytest.importorskip("onnx", reason="building the tiny ONNX models needs the 'onnx' package (test extra)")
    d = tmp_path_factory.mktemp("clip")
    torch.manual_seed(0)
    img, txt = _Img().eval(), _Txt().eval()
    torch.onnx.export(img, (torch.randn(2, 3, 32, 32),), str(d / "image.onnx"), input_names=["pixel_values"],
                      dynamic_axes={"pixel_values": {0: "n"}}, dynamo=False)
    torch.onnx.export(txt, (torch.zeros(2, 8, dtype=torch.long),), str(d / "text.onnx"), input_names=["input_ids"],
                      dynamic_axes={"input_ids": {0: "n", 1: "l"}}, dynamo=False)
    return d / "image.onnx", d / "text.onnx", _tokenizer_json(d / "tokenizer.json"), img, txt


def test_clip_onnx_wiring(onnx_pair):
    img_p, txt_p, tok_p, img, txt = onnx_pair
    g = create_backend("text_embedder", "clip-onnx", image_model=img_p, text_model=txt_p, tokenizer=tok_p,
                       context_length=8)
    assert isinstance(g, Grounder) and g.labels is None and g.dim == 16 and g.image_size == 32
    rgb = np.random.default_rng(0).integers(0, 256, (40, 50, 3), dtype=np.uint8)
    masks = np.zeros((3, 40, 50), bool)
    masks[0, 5:20, 5:30] = True
    masks[2, 10:35, 20:45] = True
    ev = g.mask_evidence(rgb, masks)
    assert ev.features.shape == (3, 16) and np.allclose(ev.grounding, ev.features)
    np.testing.assert_allclose(np.linalg.norm(ev.features, axis=1), [1, 0, 1], atol=1e-5)
    # same numbers as the torch model on the same preprocessed crops
    ref = img(torch.from_numpy(g._pixels(rgb, masks[[0]]))).detach().numpy()[0]
    np.testing.assert_allclose(ev.features[0], ref / np.linalg.norm(ref), atol=1e-4)
    t = g.embed_text(["the red mug", "banana"])
    assert t.shape == (2, 16)
    np.testing.assert_allclose(np.linalg.norm(t, axis=1), 1, atol=1e-5)


def test_clip_onnx_refuses_missing_files(tmp_path):
    with pytest.raises(Clutt3rError, match="never downloads"):
        create_backend("text_embedder", "clip-onnx")
    with pytest.raises(Clutt3rError, match="is not a file"):
        create_backend("text_embedder", "clip-onnx", image_model=tmp_path / "x.onnx", text_model=tmp_path / "y",
                       tokenizer=tmp_path / "z")


def test_clip_onnx_answers_queries_in_shared_space(onnx_pair):
    """The query path with a shared-space backend: evidence -> aggregation -> cosine ranking."""
    from clutt3r_core.query import RunQuery
    from tests.core._tiny_run import tiny_scene, tiny_segmentation

    img_p, txt_p, tok_p, *_ = onnx_pair
    g = create_backend("text_embedder", "clip-onnx", image_model=img_p, text_model=txt_p, tokenizer=tok_p)
    rq = RunQuery.from_scene(tiny_segmentation(), tiny_scene(), g)
    res = rq.query("the red mug")
    seg = tiny_segmentation()
    assert sorted(res.ranking) == list(range(seg.num_instances))
    cos = rq.instances.grounding @ g.embed_text(["mug"])[0]
    assert res.explanations[0].classes == ()
    # with no colour match the ranking is the cosine ranking (z-scoring keeps the order)
    if not any(m.share for e in res.explanations for m in e.colors):
        assert list(res.ranking) == list(np.argsort(-cos, kind="stable"))


def test_open_clip_missing_names_the_extra(monkeypatch):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: None if n == "open_clip" else real(n, *a))
    with pytest.raises(MissingDependencyError, match=r"clutt3r\[clip\]"):
        create_backend("text_embedder", "open-clip", checkpoint="/nonexistent")


def test_open_clip_wiring_with_a_stand_in_module(tmp_path, monkeypatch):
    """open-clip-torch cannot be installed on the CPU-only machine (it pulls a CUDA torch), so a
    stand-in ``open_clip`` module with open_clip's API and a tiny random model checks our adapter."""
    calls = {}

    class Model(torch.nn.Module):
        def __init__(self):
            super().__init__()
            self.visual = _Img(12)
            self.visual.image_size = 32
            self.text = _Txt(64, 12)

        def encode_image(self, x):
            return self.visual(x)

        def encode_text(self, ids):
            return self.text(ids)

    def create_model(name, pretrained=None, device="cpu"):
        calls["create"] = (name, pretrained)
        return Model()

    def get_tokenizer(name):
        return lambda texts: torch.tensor([[len(w) % 64 for w in t.split()][:4] + [0] * (4 - min(4, len(t.split())))
                                           for t in texts])

    fake = types.ModuleType("open_clip")
    fake.create_model, fake.get_tokenizer = create_model, get_tokenizer
    fake.__spec__ = types.SimpleNamespace(name="open_clip")
    monkeypatch.setitem(sys.modules, "open_clip", fake)
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda n, *a: fake.__spec__ if n == "open_clip" else real(n, *a))
    with pytest.raises(Clutt3rError, match="never downloads"):
        create_backend("text_embedder", "open-clip", model="ViT-B-32", checkpoint="laion2b_s34b_b79k")
    ckpt = tmp_path / "model.bin"
    ckpt.write_bytes(b"weights")
    g = create_backend("text_embedder", "open-clip", model="ViT-B-32", checkpoint=ckpt)
    assert calls["create"] == ("ViT-B-32", str(ckpt))
    assert g.dim == 12 and g.image_size == 32 and g.labels is None
    rgb = np.full((20, 20, 3), 128, np.uint8)
    ev = g.mask_evidence(rgb, np.ones((2, 20, 20), bool))
    np.testing.assert_allclose(np.linalg.norm(ev.features, axis=1), 1, atol=1e-5)
    assert g.embed_text(["a red mug"]).shape == (1, 12)
    json.dumps(g.version)  # the cache key part is plain text
