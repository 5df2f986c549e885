"""Photometric in-place test for views without depth (ours; ``ChangeConfig.use_photo``).

The paper's change test (projected IoU < tau_IoU) flags static objects whose projection is
a little off their new mask (5 mm splats spill over the silhouette, masks are noisy: IoU
0.52-0.74 for correct masks), and an unmatched object whose mask the detector dropped is
reported removed. Measured on the tuning pairs (seeds 100-103, RGB only): 17 static objects
flagged, 8 of them unmatched static objects with no mask covering them (docs/update.md).

What the stored cloud predicts is sharper than its silhouette: its colours. The stored points
(background included) are z-buffered into the new camera; every pixel that is the centre of a
visible stored point is predicted to show the colour of the point that wins it. Per point
centre, not per splat (a splat's rim spills onto the background), and per instance:

    agree(pixel) = min over the (2 search_px + 1)^2 neighbourhood of
                   mean_c |I_new_c - clip(g_c * colour_c, 0, 255)| <= tol
    fraction(k)  = agree / informative, over k's informative visible pixels

- ``g`` (per channel) is the exposure / white-balance change between the stored colours and
  the new image: the median ratio over the visible *background* pixels (the table: most of
  the image, and it does not move; all visible pixels when the state has no background),
  clipped to [1/``max_gain``, ``max_gain``]. The prediction is clipped as the camera saturates.
- ``tol`` = max(``tol_min``, ``tol_sigma`` x sigma), sigma = the robust noise of the
  background pixels' residuals (1.4826 x the median of their best neighbourhood residual): a noisy real camera gets a wider
  tolerance than a clean rendering; the rule stays the same.
- *Informative* pixels: a pixel whose predicted colour resembles (within ``tol``) at least
  ``context_share`` of the background colours around the instance (stored background points
  within ``context_radius``) would agree just as well if the object were gone (a dark clamp
  on a dark table, a wooden box on a wooden table); only the others are counted.

An instance is *in place* when its fraction is >= ``in_place_fraction`` (measured on seeds
100-103 without depth: static 0.78-1.00 from the 5th percentile up, moved and removed ones
0.00-0.29), *gone* when it is <= ``gone_fraction``, else unsure; it is judged only with
enough informative pixels (``ChangeConfig.photo_min_points`` / ``photo_min_informative``).
In-place instances are static whatever their projected IoU and whether or not a mask covers
them (update.py; associate.py rule 5 for unmatched ones); unmatched gone ones are removed;
the others keep the paper's rules.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from clutt3r_core.scene import Camera
from clutt3r_core.update.project import Splats, splat

__all__ = ["PhotoCheck", "photo_check"]


@dataclass(frozen=True, eq=False)
class PhotoCheck:
    """Per-instance colour agreement of the stored points with a new image (module docstring).

    Attributes:
        ids: (K,) int32 instances checked.
        visible: (K,) int64 pixels of each instance that the new camera sees: the centre pixels
            of its stored points that it wins in the z-buffer of all stored points (one per
            pixel; splat rims are not compared).
        informative: (K,) int64 of those, pixels whose predicted (stored) colour differs by more than ``tol``
            from the background around the instance (module docstring).
        agree: (K,) int64 informative pixels whose colour agrees with the new image within ``tol``.
        gain: (3,) float64 per-channel exposure gain new / stored.
        tol: agreement tolerance used, 0-255 mean absolute RGB difference.
        sigma: robust noise of the reference points' residuals, 0-255.
    """

    ids: np.ndarray
    visible: np.ndarray
    informative: np.ndarray
    agree: np.ndarray
    gain: np.ndarray
    tol: float
    sigma: float

    def __post_init__(self) -> None:
        K = len(self.ids)
        if any(a.shape != (K,) for a in (self.visible, self.informative, self.agree)) or self.gain.shape != (3,):
            raise ValueError("PhotoCheck: ids, visible, informative, agree (K,) and gain (3,) must agree")

    def index(self, k: int) -> int:
        hit = np.flatnonzero(self.ids == k)
        return int(hit[0]) if len(hit) else -1

    def fraction(self, k: int) -> float:
        """agree / informative of instance k (NaN when none is informative or k was not checked)."""
        i = self.index(k)
        if i < 0 or not self.informative[i]:
            return float("nan")
        return float(self.agree[i] / self.informative[i])

    def judged(self, k: int, min_points: int, min_informative: float = 0.0) -> bool:
        """At least ``min_points`` informative points, and at least ``min_informative`` of the
        visible points informative."""
        i = self.index(k)
        return (i >= 0 and int(self.informative[i]) >= min_points
                and self.informative[i] >= min_informative * self.visible[i])


def photo_check(points: np.ndarray, colors: np.ndarray, instance: np.ndarray, ids: np.ndarray, camera: Camera,
                rgb: np.ndarray, voxel: float, *, tol_min: float = 15.0, tol_sigma: float = 5.0,
                max_gain: float = 2.0, min_reference: int = 200, context_radius: float = 0.03,
                search_px: int = 1, context_share: float = 0.1, max_context: int = 200) -> PhotoCheck:
    """Compare the stored colours of instances ``ids`` with ``rgb`` (module docstring).

    points (N, 3) float world metres, colors (N, 3) uint8, instance (N,) int (-1 = background:
    it occludes, is the exposure reference and the context colour, never judged); every point
    takes part in the z-buffer, except instances not in ``ids`` and not background (removed
    ones are gone)."""
    from scipy.spatial import cKDTree

    ids = np.asarray(ids, np.int32)
    inst = np.asarray(instance)
    keep = (inst < 0) | np.isin(inst, ids)
    pts, col, lab = np.asarray(points)[keep], np.asarray(colors)[keep].astype(np.float64), inst[keep]
    K = len(ids)
    zeros = np.zeros(K, np.int64)
    s = splat(pts, camera, voxel)
    vis = s.visible()
    if not vis.any():
        return PhotoCheck(ids, zeros, zeros.copy(), zeros.copy(), np.ones(3), float(tol_min), 0.0)
    vv, uu, win = _centre_pixels(s, vis)
    old = col[win]
    lab_v = lab[win]
    ref = lab_v < 0
    if ref.sum() < min_reference:  # no background in the state: every visible point is the reference
        ref = np.ones(len(old), bool)
    new = rgb[vv, uu].astype(np.float64)
    gain = np.clip(np.median((new[ref] + 5.0) / (old[ref] + 5.0), axis=0), 1.0 / max_gain, max_gain)
    pred = np.clip(old * gain, 0.0, 255.0)  # the camera saturates as the prediction must
    # the best match within +-search_px pixels: a calibration or reconstruction error of a
    # pixel moves texture edges by a pixel (measured on sample_seq1)
    best = _best_match(rgb, vv, uu, pred, search_px)
    sigma = float(1.4826 * np.median(best[ref]))  # |N(0, s)| has median 0.674 s
    tol = max(float(tol_min), tol_sigma * sigma)
    ok = best <= tol
    # informative points: their colour differs from the background around the instance
    # (what the camera would see there if the instance were gone)
    informative = np.ones(len(old), bool)
    bg = lab < 0
    if bg.sum() >= min_reference:
        tree = cKDTree(pts[bg])
        bg_col = col[bg]
        for k in ids:
            sel_all = lab == k
            sel_v = lab_v == k
            if not sel_v.any():
                continue
            pk = pts[sel_all]
            if len(pk) > 300:
                pk = pk[np.random.default_rng(0).choice(len(pk), 300, replace=False)]
            near = np.unique(np.concatenate([np.asarray(x, np.int64) for x in
                                             tree.query_ball_point(pk, context_radius)] + [np.zeros(0, np.int64)]))
            if not len(near):
                continue
            if len(near) > max_context:
                near = np.random.default_rng(1).choice(near, max_context, replace=False)
            ctx = np.clip(bg_col[near] * gain, 0.0, 255.0)
            # share of the background colours around it that this pixel's colour resembles
            share = (np.abs(pred[sel_v][:, None, :] - ctx[None]).mean(axis=2) <= tol).mean(axis=1)
            informative[sel_v] = share < context_share
    lut = np.full(int(ids.max()) + 2 if K else 1, K, np.int64)
    lut[ids] = np.arange(K)
    li = np.where(lab_v >= 0, lut[np.clip(lab_v, 0, len(lut) - 1)], K)
    count = lambda m: np.bincount(li[m], minlength=K + 1)[:K].astype(np.int64)  # noqa: E731
    return PhotoCheck(ids, count(np.ones(len(li), bool)), count(informative), count(ok & informative),
                      gain.astype(np.float64), float(tol), sigma)


def _centre_pixels(s: Splats, vis: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, columns, winning point) of the centre pixels of the ``vis`` points, once each,
    each with the point that wins it in the z-buffer (a point next to a face edge can lose its
    centre to the other face)."""
    c = np.unique(s.centre[vis])
    win = s.point.reshape(-1)[c]
    c, win = c[win >= 0], win[win >= 0]
    return s.v0 + c // s.w, s.u0 + c % s.w, win


def _best_match(rgb: np.ndarray, vv: np.ndarray, uu: np.ndarray, pred: np.ndarray, search_px: int) -> np.ndarray:
    """(M,) mean absolute colour difference between ``pred`` (M, 3) and the best of the image's
    pixels within +-``search_px`` of (vv, uu)."""
    H, W = rgb.shape[:2]
    best = np.full(len(pred), np.inf)
    for dv in range(-search_px, search_px + 1):
        for du in range(-search_px, search_px + 1):
            n2 = rgb[np.clip(vv + dv, 0, H - 1), np.clip(uu + du, 0, W - 1)].astype(np.float64)
            best = np.minimum(best, np.abs(n2 - pred).mean(axis=1))
    return best


def photo_at_pose(points: np.ndarray, colors: np.ndarray, T: np.ndarray, camera: Camera, rgb: np.ndarray,
                  voxel: float, occluder_depth: np.ndarray | None, gain: np.ndarray, tol: float,
                  search_px: int = 1) -> tuple[int, float]:
    """(visible pixels, agree fraction) of one instance's points moved by T (z-buffered behind
    ``occluder_depth``), with the gain and tolerance of a ``PhotoCheck``: do the colours of an
    optimised pose match the image there? (All visible pixels count: the background around
    the new place is not known to the stored cloud.)"""
    p = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    s = splat(p, camera, voxel)
    vv, uu, win = _centre_pixels(s, s.visible(occluder_depth))
    if not len(win):
        return 0, float("nan")
    pred = np.clip(np.asarray(colors, np.float64)[win] * gain, 0.0, 255.0)
    best = _best_match(rgb, vv, uu, pred, search_px)
    return len(win), float(np.mean(best <= tol))
