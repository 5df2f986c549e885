"""New objects enter the state (ours; views with depth, ``ChangeConfig.new_objects``).

After a grasp in clutter, removing an object often reveals one that no initial view saw, and a
pushed object that no registration explains reappears as an unmatched mask. The association
reports such masks (``UpdateResult.new_masks``); with depth in the new view they also have 3D
points, so each one that shows something the updated state does not already hold becomes a new
instance:

1. **Explained pixels** (``depth.explained_pixels``): the updated scene (every instance that is
   not removed, displaced ones at their new pose, and the background points) is z-buffered into
   the new camera; a pixel whose new depth agrees with it within ``ChangeConfig.in_place_tol``
   shows something the state already holds.
2. Each new mask (largest first, so a parent whose leaves are all new is taken whole, as the
   association's parent substitution would: Sec. III-B.3) no larger than
   ``AssociationConfig.max_object_fraction`` of the image is eroded by 2 px (depth edges bleed
   onto the background, as in ``depth.mask_points``); its valid depth pixels that are not
   explained, not already taken by an earlier new instance and stand more than
   ``ChangeConfig.region_min_height`` above the support plane (the table under a removed object
   was never seen, so nothing stored explains it) are grouped by depth continuity
   (``depth.unexplained_regions``, link ``region_link``); the largest group is the object.
3. It is added when that group holds at least ``new_min_unexplained`` of the eroded mask's valid
   depth pixels (a mask mostly explained shows a known object: a static object whose own mask
   the association missed, or a displaced one already registered) and its points,
   voxel-downsampled like the state's (voxel mean of points and colours at
   ``SceneState.voxel_size``), number at least ``new_min_points``.

Without depth there is no 3D for a new mask: it stays reported only (``UpdateResult.new_masks``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import View
from clutt3r_core.update.depth import explained_pixels, unexplained_regions
from clutt3r_core.update.state import moved_points
from clutt3r_core.update.types import UpdateConfig

__all__ = ["NewCandidate", "new_object_candidates", "voxel_mean", "next_instance_id"]


@dataclass(frozen=True, eq=False)
class NewCandidate:
    """One unmatched mask that shows an object the state does not hold.

    Attributes:
        mask_index: index into the view's ``masks``.
        points: (M, 3) float32 world metres, voxel means of its unexplained depth pixels.
        colors: (M, 3) uint8 their mean colours.
        pixels: (H, W) bool the depth pixels the points came from.
        unexplained: fraction of the eroded mask's valid depth pixels in ``pixels``.
    """

    mask_index: int
    points: np.ndarray
    colors: np.ndarray
    pixels: np.ndarray
    unexplained: float

    def __post_init__(self) -> None:
        p = np.asarray(self.points, np.float32)
        c = np.asarray(self.colors, np.uint8)
        if p.ndim != 2 or p.shape[1] != 3 or c.shape != p.shape:
            raise SceneError(f"NewCandidate: points and colors must be (M, 3), got {p.shape} / {c.shape}")
        object.__setattr__(self, "points", p)
        object.__setattr__(self, "colors", c)


def voxel_mean(points: np.ndarray, colors: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) float32 mean point and (M, 3) uint8 mean colour of each occupied ``voxel`` (m)
    cell, in the order of the cells' first point (deterministic)."""
    if not len(points):
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.uint8)
    keys = np.floor(np.asarray(points, np.float64) / voxel).astype(np.int64)
    _, first, inv = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    inv = inv.reshape(-1)
    n = np.bincount(inv).astype(np.float64)
    order = np.argsort(first, kind="stable")  # cells in order of first appearance
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    inv = rank[inv]
    n = n[order]
    P = np.stack([np.bincount(inv, points[:, j], len(n)) for j in range(3)], axis=1) / n[:, None]
    C = np.stack([np.bincount(inv, colors[:, j].astype(np.float64), len(n)) for j in range(3)], axis=1) / n[:, None]
    return P.astype(np.float32), np.clip(np.round(C), 0, 255).astype(np.uint8)


def next_instance_id(state) -> int:
    """The first id that no instance of the state's chain ever had (a removed id is never
    reused): 1 + the largest present, removed or added id."""
    used = [int(x) for x in state.instance_ids]
    for h in state.history:
        used += list(h.removed) + list(h.added) + list(h.displaced) + list(h.occluded)
    return max(used, default=-1) + 1


def new_object_candidates(state, view: View, new_masks: tuple[int, ...] | list[int], motions: dict[int, np.ndarray],
                          removed: set[int], config: UpdateConfig, plane: np.ndarray | None) -> list[NewCandidate]:
    """The new masks (indices into ``view.masks``) that become instances (module docstring).
    ``motions``: instance id -> (4, 4) motion of the displaced instances; ``removed``: ids
    dropped by the update; ``plane``: the support plane [nx, ny, nz, d] (``depth.support_plane``
    of the state, as the update computes it once), or None. Returns [] without depth."""
    if view.depth is None or not len(new_masks):
        return []
    cc, ac = config.change, config.association
    cam, depth, voxel = view.camera, view.depth, state.voxel_size
    masks = view.masks
    H, W = masks.shape
    keep = np.array([k for k in state.instance_ids if int(k) not in removed]
                    + ([-1] if cc.new_background_explains else []), np.int32)
    pts = moved_points(state, motions)
    explained = explained_pixels(pts, state.instance, keep, cam, depth, voxel, cc.in_place_tol)
    valid = np.isfinite(depth) & (depth > 0)
    taken = np.zeros((H, W), bool)
    order = sorted((int(mi) for mi in new_masks), key=lambda mi: (-int(np.count_nonzero(masks.masks[mi])), mi))
    out: list[NewCandidate] = []
    for mi in order:
        m = masks.masks[mi]
        if np.count_nonzero(m) > ac.max_object_fraction * H * W:
            continue  # the table, a whole pile: not one object
        me = ndimage.binary_erosion(m, iterations=2)
        n_valid = int(np.count_nonzero(me & valid))
        if n_valid < max(cc.new_min_points, 1):
            continue
        regions = unexplained_regions(cam, depth, explained | taken | ~me, plane, cc.region_min_height,
                                      cc.region_link, 1)
        if not regions:
            continue
        px = regions[0]
        frac = int(np.count_nonzero(px)) / n_valid
        if frac < cc.new_min_unexplained:
            continue
        vs, us = np.nonzero(px)
        P, C = voxel_mean(cam.pixels_to_world(us, vs, depth[vs, us]), view.rgb[vs, us], voxel)
        if len(P) < cc.new_min_points:
            continue
        taken |= px
        out.append(NewCandidate(mi, P, C, px, frac))
    return out
