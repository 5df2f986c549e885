"""Noisy, overlapping mask candidates imitating Grounded SAM prompted with "object".

The paper (Sec. III-A, Fig. 3) observes that Grounded SAM with the prompt "object"
returns, per view, a mix of *proper* object masks, *over-segmented* parts of objects
and *under-segmented* unions of touching objects, and that these errors are
"stochastically irregular and do not consistently appear across multiple views"
(Sec. III-B). The method builds per-view containment trees from them. This module
turns a ground-truth instance map into such a candidate set:

* **proper** masks with boundary noise (a smooth random displacement of the contour
  of at most ``jitter_px`` pixels);
* **parts**: an object cut into 2-3 pieces across a random direction near its principal
  axis; with ``p_keep_whole`` the whole is emitted too (a parent with its parts as
  children);
* **unions** of 2 (sometimes 3) objects that touch in the image; with
  ``p_keep_members`` the members' own masks are emitted too (a parent with children);
* **misses** (an object has no candidate at all), more likely for small slivers;
* **spurious** small blobs (ellipses anywhere);
* one big **table** mask (everything that is not an object: table and tray).

Parents contain their children exactly at the pixel level (children are cut out of,
or unioned into, the same noisy masks), as the containment trees assume.
Every view draws from its own ``numpy.random.Generator``, so errors are independent
across views. Candidate ids are 1..M in a random order, so ids do not reveal the
structure; ``NoisyMasks.kinds`` / ``sources`` keep it for tests and benchmarks.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Literal

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import MaskCandidates

__all__ = ["MaskNoiseConfig", "MASK_NOISE_PRESETS", "MaskNoiseName", "NoisyMasks", "noisy_masks",
           "mask_noise_preset", "containment_pairs"]

MaskNoiseName = Literal["clean", "grounded-sam-like", "harsh"]
MaskKind = Literal["proper", "part", "union", "spurious", "table"]

# Reference width for the pixel-valued fields: they are scaled by width / 640.
_REF_WIDTH = 640.0


@dataclass(frozen=True)
class MaskNoiseConfig:
    """Probabilities and sizes of the mask-candidate errors (all ours, tuned by eye against the
    real Grounded-SAM candidates of the release's ``sample_seq1``: about 12 masks and 8-15
    containment pairs per 640x480 view; paper Sec. III-A describes the error types only).

    Attributes:
        min_area_frac: a candidate (or the visible part of an object) smaller than this
            fraction of the image is never emitted (SAM drops tiny regions). 0 keeps every pixel.
        p_miss: probability that a visible object gets no candidate in a view.
        p_miss_small: miss probability instead of ``p_miss`` for objects whose visible area is
            below 4 x the minimum area (heavily occluded slivers are missed more often).
        jitter_px: largest boundary displacement, pixels at 640 px image width.
        p_oversplit: probability that an object is emitted as 2-3 parts.
        p_three_parts: given a split, probability of 3 parts instead of 2.
        p_keep_whole: given a split, probability that the whole object is emitted as well.
        p_merge: probability, per pair of objects touching in the image, of one union mask.
        p_merge_grow: given a union, probability that a third touching object joins it.
        p_keep_members: given a union, probability that its members' masks are emitted as well.
        adjacency_px: objects closer than this in the image touch, pixels at 640 px width.
        spurious_mean: mean (Poisson) number of spurious blobs per view.
        spurious_area_frac: (min, max) area of a spurious blob as a fraction of the image.
        p_table: probability of the big table / tray mask.
    """

    min_area_frac: float = 4e-4
    p_miss: float = 0.05
    p_miss_small: float = 0.4
    jitter_px: float = 2.0
    p_oversplit: float = 0.15
    p_three_parts: float = 0.3
    p_keep_whole: float = 0.6
    p_merge: float = 0.12
    p_merge_grow: float = 0.25
    p_keep_members: float = 0.5
    adjacency_px: float = 3.0
    spurious_mean: float = 0.5
    spurious_area_frac: tuple[float, float] = (1e-4, 1.5e-3)
    p_table: float = 0.8

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if f.name.startswith("p_") and not 0.0 <= v <= 1.0:
                raise SceneError(f"MaskNoiseConfig.{f.name} must be a probability in [0, 1], got {v}")
        if self.min_area_frac < 0 or self.jitter_px < 0 or self.spurious_mean < 0 or self.adjacency_px < 1:
            raise SceneError("MaskNoiseConfig: sizes must be non-negative (adjacency_px >= 1)")
        lo, hi = self.spurious_area_frac
        if not 0 < lo <= hi < 1:
            raise SceneError(f"MaskNoiseConfig.spurious_area_frac must satisfy 0 < min <= max < 1, got {lo, hi}")


MASK_NOISE_PRESETS: dict[str, MaskNoiseConfig] = {
    # one exact mask per visible object plus the table: the ideal segmenter
    "clean": MaskNoiseConfig(
        min_area_frac=0.0, p_miss=0.0, p_miss_small=0.0, jitter_px=0.0, p_oversplit=0.0, p_keep_whole=0.0,
        p_merge=0.0, p_merge_grow=0.0, p_keep_members=0.0, spurious_mean=0.0, p_table=1.0,
    ),
    "grounded-sam-like": MaskNoiseConfig(),
    "harsh": MaskNoiseConfig(
        min_area_frac=6e-4, p_miss=0.12, p_miss_small=0.6, jitter_px=4.0, p_oversplit=0.3, p_three_parts=0.4,
        p_keep_whole=0.45, p_merge=0.25, p_merge_grow=0.4, p_keep_members=0.35, spurious_mean=1.5, p_table=0.9,
    ),
}


def mask_noise_preset(name: str) -> MaskNoiseConfig:
    try:
        return MASK_NOISE_PRESETS[name]
    except KeyError:
        raise SceneError(f"unknown mask-noise preset '{name}'; choose one of {sorted(MASK_NOISE_PRESETS)}") from None


@dataclass(frozen=True, eq=False)
class NoisyMasks:
    """Mask candidates of one view and how each was made.

    Attributes:
        candidates: the masks, ids 1..M (random order).
        kinds: (M,) kind of each candidate, aligned with ``candidates.ids``:
            "proper", "part", "union", "spurious" or "table".
        sources: (M,) tuple of the ground-truth object ids each candidate was made from
            (one for proper/part, 2-3 for union, none for spurious/table).
    """

    candidates: MaskCandidates
    kinds: tuple[str, ...]
    sources: tuple[tuple[int, ...], ...]

    def __post_init__(self) -> None:
        if not len(self.kinds) == len(self.sources) == len(self.candidates):
            raise SceneError("NoisyMasks: kinds and sources must align with the candidates")


def _bbox(m: np.ndarray, pad: int) -> tuple[slice, slice]:
    rows = np.flatnonzero(m.any(1))
    cols = np.flatnonzero(m.any(0))
    H, W = m.shape
    return (slice(max(rows[0] - pad, 0), min(rows[-1] + pad + 1, H)),
            slice(max(cols[0] - pad, 0), min(cols[-1] + pad + 1, W)))


def _jitter(m: np.ndarray, r: float, rng: np.random.Generator) -> np.ndarray:
    """Move the contour of ``m`` by a smooth random offset in [-r, r] pixels."""
    if r <= 0 or not m.any():
        return m.copy()
    import cv2

    pad = int(np.ceil(r)) + 2
    sl = _bbox(m, pad)
    c = m[sl].astype(np.uint8)
    h, w = c.shape
    din = cv2.distanceTransform(c, cv2.DIST_L2, 3)
    dout = cv2.distanceTransform(1 - c, cv2.DIST_L2, 3)
    sd = np.where(c > 0, din, -dout + 1.0)  # > 0 inside, boundary pixels at 1
    # smooth noise: a coarse grid (one node per ~12 px) upsampled bicubically
    gh, gw = max(2, h // 12 + 2), max(2, w // 12 + 2)
    field = cv2.resize(rng.uniform(-1, 1, size=(gh, gw)).astype(np.float32), (w, h), interpolation=cv2.INTER_CUBIC)
    offset = rng.uniform(-0.5, 0.5)
    out_c = sd + r * np.clip(0.7 * field + offset, -1, 1) > 0.5
    out = np.zeros_like(m)
    out[sl] = out_c
    return out


def _split(m: np.ndarray, k: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Cut ``m`` into ``k`` parts across a direction near its principal axis."""
    vs, us = np.nonzero(m)
    p = np.stack([us, vs], 1).astype(np.float64)
    p -= p.mean(0)
    cov = p.T @ p / max(len(p), 1)
    w, V = np.linalg.eigh(cov)
    ang = np.arctan2(V[1, -1], V[0, -1]) + rng.uniform(-0.5, 0.5)
    s = p @ np.array([np.cos(ang), np.sin(ang)])
    if k == 2:
        qs = [rng.uniform(0.3, 0.7)]
    else:
        a = rng.uniform(0.22, 0.42)
        qs = [a, a + rng.uniform(0.22, 0.78 - a)]
    cuts = np.quantile(s, qs)
    label = np.searchsorted(cuts, s)
    parts = []
    for j in range(k):
        pm = np.zeros_like(m)
        sel = label == j
        pm[vs[sel], us[sel]] = True
        parts.append(pm)
    return parts


def _touching_pairs(inst: np.ndarray, d: int) -> np.ndarray:
    """(P, 2) int pairs (a < b) of object ids whose pixels come within ``d`` pixels."""
    K = int(inst.max()) + 2
    codes = []
    H, W = inst.shape
    for dy, dx in ((0, d), (d, 0), (d, d), (d, -d)):
        if dy >= H or abs(dx) >= W:
            continue
        if dx >= 0:
            a, b = inst[: H - dy, : W - dx], inst[dy:, dx:]
        else:
            a, b = inst[: H - dy, -dx:], inst[dy:, : W + dx]
        ok = (a >= 0) & (b >= 0) & (a != b)
        lo = np.minimum(a[ok], b[ok]).astype(np.int64)
        hi = np.maximum(a[ok], b[ok]).astype(np.int64)
        codes.append(lo * K + hi)
    u = np.unique(np.concatenate(codes)) if codes else np.zeros(0, np.int64)
    return np.stack([u // K, u % K], 1)


def noisy_masks(
    instance: np.ndarray,
    cfg: MaskNoiseConfig,
    rng: np.random.Generator,
    *,
    valid: np.ndarray | None = None,
) -> NoisyMasks:
    """Mask candidates for one view from its ground-truth instance map.

    Args:
        instance: (H, W) int32 object id per pixel, -1 for background.
        cfg: the error model.
        rng: this view's generator (seed it per view so errors are independent across views).
        valid: optional (H, W) bool, pixels that see a surface (the table mask is limited to
            them); default every pixel.
    """
    inst = np.asarray(instance)
    if inst.ndim != 2:
        raise SceneError(f"instance map must be (H, W), got shape {inst.shape}")
    H, W = inst.shape
    scale = W / _REF_WIDTH
    min_area = cfg.min_area_frac * H * W
    jit = cfg.jitter_px * scale
    ids, counts = np.unique(inst[inst >= 0], return_counts=True)
    visible = {int(i): int(c) for i, c in zip(ids, counts) if c > 0 and c >= min_area}

    out: list[tuple[np.ndarray, str, tuple[int, ...], float]] = []

    def emit(m: np.ndarray, kind: str, src: tuple[int, ...], score: float) -> None:
        if m.any() and m.sum() >= max(min_area, 1):
            out.append((m, kind, src, score))

    # misses: one draw per visible object, in id order (stable for a seed)
    present = []
    for k in sorted(visible):
        p = cfg.p_miss_small if visible[k] < 4 * min_area else cfg.p_miss
        if rng.uniform() >= p:
            present.append(k)
    present_set = set(present)

    # unions of touching objects
    unions: list[tuple[list[int], bool]] = []
    in_union: set[int] = set()
    if cfg.p_merge > 0 and len(present) > 1:
        pairs = _touching_pairs(inst, max(1, int(round(cfg.adjacency_px * scale))))
        pairs = pairs[np.isin(pairs[:, 0], present) & np.isin(pairs[:, 1], present)]
        for a, b in pairs[rng.permutation(len(pairs))]:
            a, b = int(a), int(b)
            if rng.uniform() >= cfg.p_merge or a in in_union or b in in_union:
                continue
            members = [a, b]
            if rng.uniform() < cfg.p_merge_grow:
                nb = [int(c) for pr in pairs for c in pr
                      if (pr[0] in members or pr[1] in members) and int(c) not in members
                      and int(c) not in in_union]
                if nb:
                    members.append(nb[int(rng.integers(len(nb)))])
            in_union.update(members)
            unions.append((members, rng.uniform() < cfg.p_keep_members))
    keep_individual = present_set - in_union
    for members, keep in unions:
        if keep:
            keep_individual.update(members)

    # per object: proper mask, or parts (with or without the whole)
    emitted_of: dict[int, np.ndarray] = {}
    for k in sorted(keep_individual):
        gt = inst == k
        m = _jitter(gt, jit, rng)
        emitted_of[k] = m
        if rng.uniform() < cfg.p_oversplit and m.sum() >= 2 * max(min_area, 1):
            nparts = 3 if rng.uniform() < cfg.p_three_parts else 2
            for part in _split(m, nparts, rng):
                emit(part, "part", (k,), rng.uniform(0.3, 0.7))
            if rng.uniform() < cfg.p_keep_whole:
                emit(m, "proper", (k,), rng.uniform(0.5, 0.9))
        else:
            emit(m, "proper", (k,), rng.uniform(0.55, 0.95))
    for members, keep in unions:
        m = _jitter(np.isin(inst, members), jit, rng)
        if keep:
            for k in members:
                m |= emitted_of[k]  # the parent contains its children exactly
        emit(m, "union", tuple(sorted(members)), rng.uniform(0.35, 0.75))

    # spurious blobs
    if cfg.spurious_mean > 0:
        import cv2

        lo, hi = cfg.spurious_area_frac
        for _ in range(int(rng.poisson(cfg.spurious_mean))):
            area = np.exp(rng.uniform(np.log(lo), np.log(hi))) * H * W
            ratio = rng.uniform(0.4, 1.0)
            a = np.sqrt(area / (np.pi * ratio))
            img = np.zeros((H, W), np.uint8)
            centre = (int(rng.integers(W)), int(rng.integers(H)))
            cv2.ellipse(img, centre, (max(1, int(round(a))), max(1, int(round(a * ratio)))),
                        float(rng.uniform(0, 180)), 0, 360, 1, -1)
            emit(img.astype(bool), "spurious", (), rng.uniform(0.3, 0.5))

    # the table / tray
    if rng.uniform() < cfg.p_table:
        bg = inst < 0
        if valid is not None:
            bg &= np.asarray(valid, bool)
        emit(_jitter(bg, jit, rng), "table", (), rng.uniform(0.3, 0.6))

    order = rng.permutation(len(out))
    ids_out = np.empty(len(out), np.int32)
    ids_out[order] = np.arange(1, len(out) + 1, dtype=np.int32)
    srt = np.argsort(ids_out)  # store by id, 1..M
    masks = np.stack([out[i][0] for i in srt]) if out else np.zeros((0, H, W), bool)
    cands = MaskCandidates(masks, ids_out[srt], np.array([out[i][3] for i in srt], np.float32))
    return NoisyMasks(cands, tuple(out[i][1] for i in srt), tuple(out[i][2] for i in srt))


def containment_pairs(masks: np.ndarray, tol: float = 0.0) -> np.ndarray:
    """(P, 2) int (parent index, child index) where child ⊆ parent up to ``tol`` of the child's area.

    Identical masks count once (lower index is the parent). Uses one sparse-free
    matrix product over the flattened masks.
    """
    m = np.asarray(masks, bool).reshape(len(masks), -1).astype(np.float32)
    if len(m) == 0:
        return np.zeros((0, 2), np.int64)
    inter = m @ m.T
    area = np.diag(inter)
    inside = inter >= (1.0 - tol) * area[None, :]  # [i, j]: j inside i
    np.fill_diagonal(inside, False)
    same = inside & inside.T
    inside &= ~(same & (np.arange(len(m))[:, None] > np.arange(len(m))[None, :]))
    inside &= area[None, :] > 0
    return np.argwhere(inside)

