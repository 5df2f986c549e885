"""Before/after overlays of an update (for docs, the CLI and the viewer).

``update_overlay`` draws, on the new image: left, the stored instances z-buffered into the
new camera BEFORE the update (filled, instance colours) with each matched new mask's outline;
right, the same AFTER the update (displaced instances moved, removed ones gone). Removed
instances are outlined in red on the left; the status of each instance is written in the legend
strip under the images.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from clutt3r_core.scene import View
from clutt3r_core.update.associate import project_instances
from clutt3r_core.update.state import SceneState, apply_update
from clutt3r_core.update.types import UpdateResult
from clutt3r_core.visualize import instance_palette

__all__ = ["update_overlay"]

_STATUS_RGB = {"static": (160, 160, 160), "displaced": (255, 200, 0), "removed": (255, 40, 40), "occluded": (80, 160, 255),
               "new": (40, 200, 80)}


def _fill(img: np.ndarray, label: np.ndarray, pal: np.ndarray, alpha: float = 0.55) -> np.ndarray:
    out = img.astype(np.float32)
    hit = label >= 0
    out[hit] = (1 - alpha) * out[hit] + alpha * pal[label[hit]]
    return out


def _outline(img: np.ndarray, mask: np.ndarray, rgb, width: int = 2) -> None:
    edge = mask & ~ndimage.binary_erosion(mask, iterations=width)
    img[edge] = rgb


def update_overlay(state: SceneState, view: View, result: UpdateResult) -> np.ndarray:
    """(H + legend, 2 W, 3) uint8: before | after (module docstring)."""
    cam = view.camera
    n = int(max(state.instance_ids.max(initial=-1), max((r.instance for r in result.instances), default=0), 0)) + 1
    pal = instance_palette(n).astype(np.float32)
    before = project_instances(state.points, state.instance, state.instance_ids, cam, state.voxel_size)
    after_state = apply_update(state, result)
    after = project_instances(after_state.points, after_state.instance, after_state.instance_ids, cam,
                              state.voxel_size)
    left = _fill(view.rgb, before.label, pal)
    right = _fill(view.rgb, after.label, pal)
    for i, r in enumerate(result.instances):
        col = pal[r.instance]
        if result.change_masks[i].any():
            _outline(left, result.change_masks[i], col)
            _outline(right, result.change_masks[i], col)
        if r.status == "removed":
            _outline(left, before.label == r.instance, _STATUS_RGB["removed"], 3)
        if r.status == "displaced":
            _outline(left, before.label == r.instance, _STATUS_RGB["displaced"], 1)
    img = np.concatenate([left, right], axis=1).clip(0, 255).astype(np.uint8)
    return np.concatenate([img, _legend(result, pal, img.shape[1])], axis=0)


def _legend(result: UpdateResult, pal: np.ndarray, width: int) -> np.ndarray:
    """One swatch per instance (its colour) with a status bar under it (status colour)."""
    k = len(result.instances)
    sw = max(8, min(40, width // max(k, 1)))
    strip = np.full((24, width, 3), 255, np.uint8)
    for i, r in enumerate(result.instances):
        x0 = i * sw
        if x0 + sw > width:
            break
        strip[2:14, x0 + 2 : x0 + sw - 2] = pal[r.instance].astype(np.uint8)
        strip[16:22, x0 + 2 : x0 + sw - 2] = _STATUS_RGB[r.status]
    return strip
