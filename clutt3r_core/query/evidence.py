"""Per-mask evidence of a run and its multi-view aggregation into instance evidence.

The paper embeds each group's per-view instance images and aggregates the cross-view
evidence into one instance embedding (Sec. III-D). Here every mask that ended in an
instance is described once (``NodeEvidence``: image features, grounding vector, colour
shares, pixel area), cached in ``RUN/query_cache.npz``, and aggregated per instance
(``InstanceEvidence``) as a weighted mean over the instance's masks, one per view.

Cache: ``query_cache.npz`` holds the node evidence, the backend's label embeddings (label
mode) and a key: SHA-256 of the run's ``trace/trace.json`` and ``instances.npz`` plus the
backend's name and (image-side) version. A different key (the run was re-segmented,
another backend) means the evidence is recomputed, never reused. Colour shares (rules
versioned by ``COLOR_VERSION``) and label embeddings (compared by their label texts) are
refreshed on their own when they are stale, without re-running the image network.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.language.colors import COLOR_VERSION, COLOR_WORDS, color_shares

__all__ = [
    "CACHE_NAME",
    "NodeEvidence",
    "InstanceEvidence",
    "instance_node_lists",
    "compute_node_evidence",
    "refresh_colors",
    "refresh_labels",
    "aggregate_instances",
    "run_cache_key",
    "save_node_evidence",
    "load_node_evidence",
]

CACHE_NAME = "query_cache.npz"
LOGP_FLOOR = float(np.log(1e-8))
"""Log-probabilities are floored here before averaging (one view's 1e-30 must not veto a class)."""


@dataclass(frozen=True, eq=False)
class NodeEvidence:
    """Evidence of the masks (trace nodes) that make the run's instances.

    Attributes:
        nodes: (U,) int64 node indices into ``trace.nodes``, ascending.
        features: (U, D) float32 unit image features.
        grounding: (U, G) float32 grounding vectors (``clutt3r_core.language.base``).
        colors: (U, C) float32 share of mask pixels per ``COLOR_WORDS``.
        area: (U,) float32 mask area in pixels.
        image_area: (U,) float32 pixels of the mask's image (areas are compared as fractions).
        backend: name of the backend; version: its version.
        label_embeddings: (L, Dt) float32 text embeddings of the backend's labels, or None
            (shared-space backend).
        labels: the label texts (label mode), else ().
        color_version: ``COLOR_VERSION`` of the rules that named the colours.
    """

    nodes: np.ndarray
    features: np.ndarray
    grounding: np.ndarray
    colors: np.ndarray
    area: np.ndarray
    image_area: np.ndarray
    backend: str
    version: str
    label_embeddings: np.ndarray | None = None
    labels: tuple[str, ...] = ()
    color_version: str = COLOR_VERSION

    def __post_init__(self) -> None:
        u = len(self.nodes)
        for nm in ("features", "grounding", "colors"):
            a = getattr(self, nm)
            if a.ndim != 2 or a.shape[0] != u:
                raise SceneError(f"NodeEvidence.{nm}: expected ({u}, ...) rows, got {a.shape}")
        if self.colors.shape[1] != len(COLOR_WORDS):
            raise SceneError(f"NodeEvidence.colors: expected {len(COLOR_WORDS)} columns, got {self.colors.shape[1]}")
        if self.area.shape != (u,) or self.image_area.shape != (u,):
            raise SceneError("NodeEvidence: area and image_area must be (U,)")
        if self.label_embeddings is not None and len(self.label_embeddings) != len(self.labels):
            raise SceneError("NodeEvidence: one label embedding per label")


@dataclass(frozen=True, eq=False)
class InstanceEvidence:
    """Instance evidence, aggregated over each instance's masks (one per view).

    Attributes:
        grounding: (I, G) float32 weighted mean of the masks' grounding vectors (label mode:
            mean log-probability, i.e. the log of the geometric mean over views).
        colors: (I, C) float32 weighted mean colour shares.
        features: (I, D) float32 unit, normalised weighted mean of the mask features.
        n_views: (I,) int32 masks (views) that contributed.
    """

    grounding: np.ndarray
    colors: np.ndarray
    features: np.ndarray
    n_views: np.ndarray

    @property
    def num_instances(self) -> int:
        return len(self.n_views)


def instance_node_lists(seg) -> list[tuple[int, ...]]:
    """Node indices of each instance's masks (``Segmentation.instance_nodes``)."""
    return [tuple(int(i) for i in seg.instance_nodes(k)) for k in range(seg.num_instances)]


def _view_masks(seg, scene, nodes: np.ndarray):
    """Yield (view, rows of ``nodes`` in that view, their masks (m, H, W) bool), view by view."""
    tr = seg.trace
    views = {int(v.frame): v for v in scene.initial_views}
    by_frame: dict[int, list[int]] = {}
    for j, i in enumerate(nodes):
        f = int(tr.nodes.frame[i])
        if f not in views:
            raise SceneError(f"{scene.name or 'scene'}: the run names frame {f}, which the scene does not have")
        by_frame.setdefault(f, []).append(j)
    for f, js in sorted(by_frame.items()):
        v = views[f]
        if v.masks is None:
            raise SceneError(f"{v.name or f}: view has no mask candidates")
        idx = [v.masks.index_of(int(tr.nodes.mask_id[nodes[j]])) for j in js]
        yield v, js, v.masks.stack(idx)  # only these masks, materialised for this view and not kept


def refresh_colors(ev: NodeEvidence, seg, scene) -> NodeEvidence:
    """``ev`` with its colour shares recomputed by the current rules (no network involved)."""
    colors = np.zeros_like(ev.colors)
    for v, js, masks in _view_masks(seg, scene, ev.nodes):
        colors[js] = color_shares(v.rgb, masks)
    return replace(ev, colors=colors, color_version=COLOR_VERSION)


def refresh_labels(ev: NodeEvidence, grounder) -> NodeEvidence:
    """``ev`` with the backend's current label texts and their embeddings."""
    labels = tuple(grounder.labels) if grounder.labels is not None else ()
    emb = np.asarray(grounder.label_embeddings(), np.float32) if labels else None
    return replace(ev, labels=labels, label_embeddings=emb)


def compute_node_evidence(seg, scene, grounder, progress: bool = False) -> NodeEvidence:
    """Describe every mask that belongs to an instance of ``seg`` with ``grounder``.

    ``scene``: the scene the run was made from (its initial views carry the images and
    the mask candidates named by the trace's nodes).
    """
    nodes = np.array(sorted({i for g in instance_node_lists(seg) for i in g}), np.int64)
    u = len(nodes)
    feats = grounding = None
    colors = np.zeros((u, len(COLOR_WORDS)), np.float32)
    area = np.zeros(u, np.float32)
    image_area = np.zeros(u, np.float32)
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=u, desc="embedding masks", unit="mask", leave=False)
    for v, js, masks in _view_masks(seg, scene, nodes):
        ev = grounder.mask_evidence(v.rgb, masks)
        if feats is None:
            feats = np.zeros((u, ev.features.shape[1]), np.float32)
            grounding = np.zeros((u, ev.grounding.shape[1]), np.float32)
        feats[js] = ev.features
        grounding[js] = ev.grounding
        colors[js] = color_shares(v.rgb, masks)
        area[js] = masks.reshape(len(js), -1).sum(axis=1)
        image_area[js] = masks.shape[1] * masks.shape[2]
        if bar is not None:
            bar.update(len(js))
    if bar is not None:
        bar.close()
    if feats is None:
        feats = np.zeros((0, grounder.dim), np.float32)
        g = len(grounder.labels) if grounder.labels is not None else grounder.dim
        grounding = np.zeros((0, g), np.float32)
    labels = tuple(grounder.labels) if grounder.labels is not None else ()
    lab_emb = np.asarray(grounder.label_embeddings(), np.float32) if labels else None
    return NodeEvidence(nodes, feats, grounding, colors, area, image_area, grounder.name,
                        str(getattr(grounder, "version", "")), lab_emb, labels)


def aggregate_instances(seg, ev: NodeEvidence, label_mode: bool, area_power: float = 0.5) -> InstanceEvidence:
    """Weighted mean of each instance's mask evidence; weight = (area fraction) ** area_power.

    Why area: a mask's crop is resized to the encoder's input, so a small (far, occluded,
    truncated) view of an object is a blurrier, less reliable look at it; the square root
    keeps one big view from drowning the others (ours; ``benchmarks/bench_query.py``).
    """
    groups = instance_node_lists(seg)
    row = {int(n): j for j, n in enumerate(ev.nodes)}
    k = len(groups)
    g = ev.grounding.shape[1]
    out_g = np.zeros((k, g), np.float32)
    out_c = np.zeros((k, ev.colors.shape[1]), np.float32)
    out_f = np.zeros((k, ev.features.shape[1]), np.float32)
    n_views = np.zeros(k, np.int32)
    grounding = np.maximum(ev.grounding, LOGP_FLOOR) if label_mode else ev.grounding
    for i, grp in enumerate(groups):
        if not grp:  # an unvoted-fallback instance (segmentation.unvoted) has no masks: no evidence
            out_g[i] = LOGP_FLOOR if label_mode else 0.0
            continue
        js = [row[n] for n in grp if n in row]
        if not js:
            raise SceneError(f"instance {i}: none of its masks has evidence (stale cache?)")
        w = (ev.area[js] / np.maximum(ev.image_area[js], 1.0)) ** area_power
        w = w / w.sum() if w.sum() > 0 else np.full(len(js), 1.0 / len(js))
        out_g[i] = w @ grounding[js]
        out_c[i] = w @ ev.colors[js]
        f = w @ ev.features[js]
        out_f[i] = f / max(float(np.linalg.norm(f)), 1e-12)
        n_views[i] = len(js)
    if not label_mode:  # shared space: compare directions
        out_g /= np.maximum(np.linalg.norm(out_g, axis=1, keepdims=True), 1e-12)
    return InstanceEvidence(out_g, out_c, out_f, n_views)


def run_cache_key(run_dir: str | Path, backend: str, version: str) -> str:
    """Identity of a run's grouping and of the backend (see module docstring)."""
    run_dir = Path(run_dir)
    h = hashlib.sha256()
    for rel in ("trace/trace.json", "instances.npz"):
        h.update((run_dir / rel).read_bytes())
    h.update(f"\0{backend}\0{version}".encode())
    return h.hexdigest()


def save_node_evidence(ev: NodeEvidence, path: str | Path, key: str) -> Path:
    from clutt3r_core.io.images import atomic_write_bytes

    arrays = dict(
        key=np.array(key), backend=np.array(ev.backend), version=np.array(ev.version),
        nodes=ev.nodes, features=ev.features.astype(np.float16), grounding=ev.grounding.astype(np.float32),
        colors=ev.colors, area=ev.area, image_area=ev.image_area, labels=np.array(ev.labels, dtype=str),
        color_version=np.array(ev.color_version),
    )
    if ev.label_embeddings is not None:
        arrays["label_embeddings"] = ev.label_embeddings.astype(np.float32)
    buf = io.BytesIO()
    np.savez(buf, **arrays)  # uncompressed: loading is on the query's critical path
    atomic_write_bytes(Path(path), buf.getvalue())
    return Path(path)


def load_node_evidence(path: str | Path, key: str) -> NodeEvidence | None:
    """The cached evidence, or None when absent or made for another key."""
    path = Path(path)
    if not path.is_file():
        return None
    try:
        with np.load(path) as z:
            if str(z["key"]) != key:
                return None
            lab = z["label_embeddings"] if "label_embeddings" in z.files else None
            return NodeEvidence(
                nodes=z["nodes"].astype(np.int64), features=z["features"].astype(np.float32),
                grounding=z["grounding"].astype(np.float32), colors=z["colors"], area=z["area"],
                image_area=z["image_area"], backend=str(z["backend"]), version=str(z["version"]),
                label_embeddings=lab, labels=tuple(str(s) for s in z["labels"]),
                color_version=str(z["color_version"]) if "color_version" in z.files else "",
            )
    except (OSError, ValueError, KeyError) as e:
        raise SceneFileError(path, f"unreadable query cache ({e}); delete it to recompute") from None
