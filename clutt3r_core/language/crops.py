"""Mask crops for image encoders: the mask's bounding box with the pixels outside the mask
set to white (Sec. III-D: "replacing the background outside each mask with white"),
letterboxed (padded to a square, on white) and resized to the encoder's input."""

from __future__ import annotations

import numpy as np

__all__ = ["mask_crops"]


def mask_crops(rgb: np.ndarray, masks: np.ndarray, size: int = 224, margin: float = 0.1) -> np.ndarray:
    """(M, size, size, 3) uint8 letterboxed crops of each mask (all white for an empty mask).

    Args:
        rgb: (H, W, 3) uint8 image.
        masks: (M, H, W) bool.
        size: output side in pixels (the encoder's input size).
        margin: white border around the mask's box, as a fraction of the box's longer side
            (ours: keeps the object's silhouette off the crop's edge, where convolutions pad).
    """
    import cv2

    m = masks.shape[0]
    out = np.full((m, size, size, 3), 255, np.uint8)
    for i in range(m):
        rows = np.flatnonzero(masks[i].any(axis=1))
        if rows.size == 0:
            continue
        cols = np.flatnonzero(masks[i].any(axis=0))
        r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        patch = np.where(masks[i, r0:r1, c0:c1, None], rgb[r0:r1, c0:c1], np.uint8(255))
        h, w = r1 - r0, c1 - c0
        side = int(np.ceil(max(h, w) * (1.0 + 2.0 * margin)))
        canvas = np.full((side, side, 3), 255, np.uint8)
        y, x = (side - h) // 2, (side - w) // 2
        canvas[y:y + h, x:x + w] = patch
        interp = cv2.INTER_AREA if side > size else cv2.INTER_LINEAR
        out[i] = cv2.resize(canvas, (size, size), interpolation=interp)
    return out
