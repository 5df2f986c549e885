"""Backends for users who have CLIP weights on disk: ``open-clip`` and ``clip-onnx``.

Both are *shared-space* grounders (``clutt3r_core.language.base``): a mask's features and
grounding vector are its unit CLIP image embedding, a query's score is the cosine with its
unit text embedding. Masks are cropped on white (``crops.mask_crops``) and normalised with
the CLIP mean / std (OpenAI's values unless given).

No download path: both take local file paths and refuse anything else.

* ``open-clip`` (extra ``clip``, ``open-clip-torch``): ``OpenClip(model="ViT-B-32",
  checkpoint="/path/to/open_clip_model.bin")``. The checkpoint must be an existing file;
  an open_clip *tag* (which open_clip would download) is refused. Note: open-clip-torch
  needs torchvision, which pulls a CUDA torch from PyPI; install it into an environment
  whose torch matches (not on the project's CPU-only machines).
* ``clip-onnx`` (onnxruntime, a core dependency): ``ClipOnnx(image_model=..., text_model=...,
  tokenizer=...)``: an image encoder taking (N, 3, S, S) float32 and returning (N, D), a text
  encoder taking (N, L) int64 token ids and returning (N, D), and a ``tokenizers``
  ``tokenizer.json`` (as Hugging Face CLIP exports ship).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError, MissingDependencyError
from clutt3r_core.language.base import MaskEvidence
from clutt3r_core.language.crops import mask_crops

__all__ = ["OpenClip", "ClipOnnx", "CLIP_MEAN", "CLIP_STD"]

CLIP_MEAN = (0.48145466, 0.4578275, 0.40821073)
CLIP_STD = (0.26862954, 0.26130258, 0.27577711)
"""OpenAI CLIP's input normalisation (RGB, on 0..1 values)."""


def _existing_file(path, what: str) -> Path:
    if path is None or str(path) == "":
        raise Clutt3rError(f"{what}: a local file path is required (this backend never downloads weights)")
    p = Path(path).expanduser()
    if not p.is_file():
        raise Clutt3rError(f"{what}: {p} is not a file (this backend never downloads weights)")
    return p


def _unit(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, np.float32)
    n = np.linalg.norm(x, axis=1, keepdims=True)
    return np.divide(x, n, out=np.zeros_like(x), where=n > 0)


class _ClipCommon:
    """Crops, normalisation and the MaskEvidence of a shared-space CLIP-like backend."""

    name = "clip"
    version = "1"
    dim = 0
    image_size = 224
    batch_size = 32
    mean = CLIP_MEAN
    std = CLIP_STD

    @property
    def labels(self) -> None:
        return None

    def label_embeddings(self) -> np.ndarray:
        raise Clutt3rError(f"{self.name} compares text and images directly; it has no label set")

    def _pixels(self, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
        crops = mask_crops(rgb, masks, self.image_size).astype(np.float32) / 255.0
        x = (crops - np.asarray(self.mean, np.float32)) / np.asarray(self.std, np.float32)
        return np.ascontiguousarray(x.transpose(0, 3, 1, 2))

    def _encode_images(self, x: np.ndarray) -> np.ndarray:  # (N, 3, S, S) -> (N, D)
        raise NotImplementedError

    def mask_evidence(self, rgb: np.ndarray, masks: np.ndarray) -> MaskEvidence:
        m = masks.shape[0]
        out = np.zeros((m, self.dim), np.float32)
        nonempty = np.flatnonzero(masks.reshape(m, -1).any(axis=1)) if m else np.zeros(0, np.int64)
        for s in range(0, len(nonempty), self.batch_size):
            idx = nonempty[s:s + self.batch_size]
            out[idx] = _unit(self._encode_images(self._pixels(rgb, masks[idx])))
        return MaskEvidence(features=out, grounding=out.copy())

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
        return self.mask_evidence(rgb, masks).features


class OpenClip(_ClipCommon):
    """open_clip model built from a local checkpoint file (see module docstring)."""

    name = "open-clip"

    def __init__(self, model: str = "ViT-B-32", checkpoint: str | Path | None = None, batch_size: int = 32) -> None:
        if importlib.util.find_spec("open_clip") is None:
            raise MissingDependencyError("the language backend 'open-clip'", "open-clip-torch", "clip")
        ckpt = _existing_file(checkpoint, "open-clip checkpoint")
        import open_clip
        import torch

        self._torch = torch
        self.model_name = model
        self.model = open_clip.create_model(model, pretrained=str(ckpt), device="cpu").eval()
        self.tokenizer = open_clip.get_tokenizer(model)
        size = getattr(getattr(self.model, "visual", None), "image_size", 224)
        self.image_size = int(size[0] if isinstance(size, (tuple, list)) else size)
        self.batch_size = int(batch_size)
        self.version = f"1:{model}:{ckpt.name}:{ckpt.stat().st_size}"
        with torch.inference_mode():
            self.dim = int(self.model.encode_text(self.tokenizer(["a"])).shape[-1])

    def _encode_images(self, x: np.ndarray) -> np.ndarray:
        with self._torch.inference_mode():
            return self.model.encode_image(self._torch.from_numpy(x)).float().numpy()

    def embed_text(self, texts: list[str]) -> np.ndarray:
        with self._torch.inference_mode():
            return _unit(self.model.encode_text(self.tokenizer(list(texts))).float().numpy())


class ClipOnnx(_ClipCommon):
    """A CLIP image / text encoder pair exported to ONNX, run with onnxruntime."""

    name = "clip-onnx"

    def __init__(
        self,
        image_model: str | Path | None = None,
        text_model: str | Path | None = None,
        tokenizer: str | Path | None = None,
        context_length: int = 77,
        image_size: int | None = None,
        mean: tuple[float, float, float] = CLIP_MEAN,
        std: tuple[float, float, float] = CLIP_STD,
        batch_size: int = 32,
    ) -> None:
        if importlib.util.find_spec("onnxruntime") is None:
            raise MissingDependencyError("the language backend 'clip-onnx'", "onnxruntime", None)
        if importlib.util.find_spec("tokenizers") is None:
            raise MissingDependencyError("the language backend 'clip-onnx'", "tokenizers", "language")
        img = _existing_file(image_model, "clip-onnx image_model")
        txt = _existing_file(text_model, "clip-onnx text_model")
        tok = _existing_file(tokenizer, "clip-onnx tokenizer (tokenizer.json)")
        import onnxruntime as ort
        from tokenizers import Tokenizer

        opts = ort.SessionOptions()
        opts.log_severity_level = 3
        self.image_session = ort.InferenceSession(str(img), opts, providers=["CPUExecutionProvider"])
        self.text_session = ort.InferenceSession(str(txt), opts, providers=["CPUExecutionProvider"])
        self.tokenizer = Tokenizer.from_file(str(tok))
        self.tokenizer.enable_truncation(int(context_length))
        pad_id = self.tokenizer.token_to_id("<|endoftext|>")
        self.tokenizer.enable_padding(pad_id=0 if pad_id is None else pad_id, length=int(context_length))
        shape = self.image_session.get_inputs()[0].shape
        inferred = shape[-1] if isinstance(shape[-1], int) else 224
        self.image_size = int(image_size or inferred)
        self.mean, self.std = tuple(mean), tuple(std)
        self.batch_size = int(batch_size)
        self.dim = int(self.embed_text(["a"]).shape[1])
        self.version = f"1:{img.name}:{img.stat().st_size}:{txt.name}:{txt.stat().st_size}"

    def _encode_images(self, x: np.ndarray) -> np.ndarray:
        inp = self.image_session.get_inputs()[0].name
        return self.image_session.run(None, {inp: x.astype(np.float32)})[0]

    def embed_text(self, texts: list[str]) -> np.ndarray:
        enc = self.tokenizer.encode_batch(list(texts))
        ids = np.array([e.ids for e in enc], np.int64)
        inp = self.text_session.get_inputs()[0].name
        return _unit(self.text_session.run(None, {inp: ids})[0])
