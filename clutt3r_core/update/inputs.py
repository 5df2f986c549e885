"""Reading a post-interaction image from outside a scene (``clutt3r update STATE --image ...``)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import read_depth_mm, read_mask, read_rgb
from clutt3r_core.scene import Camera, MaskCandidates, View

__all__ = ["read_camera_json", "read_mask_folder", "read_external_view"]


def read_camera_json(path: str | Path) -> Camera:
    """A camera file: either ``{"K": 3x3, "width", "height", "T_world_camera": 4x4}`` or one
    nerfstudio frame ``{"fl_x", "fl_y", "cx", "cy", "w", "h", "transform_matrix"}`` (OpenCV axes,
    camera-to-world, metres; docs/conventions.md)."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as e:
        raise SceneFileError(path, f"unreadable camera JSON: {e}") from None
    try:
        if "K" in d:
            return Camera.from_json(d)
        K = [[d["fl_x"], 0, d["cx"]], [0, d["fl_y"], d["cy"]], [0, 0, 1]]
        return Camera(np.asarray(K, float), int(d["w"]), int(d["h"]), np.asarray(d["transform_matrix"], float))
    except KeyError as e:
        raise SceneFileError(path, f"camera JSON lacks the field {e}; expected K/width/height/T_world_camera "
                                   "or fl_x/fl_y/cx/cy/w/h/transform_matrix") from None
    except SceneError as e:
        raise SceneFileError(path, str(e)) from None


def read_mask_folder(folder: str | Path, hw: tuple[int, int]) -> MaskCandidates:
    """Every ``*.png`` of a folder as one mask candidate (non-zero = in). The id is the number
    after the last underscore of the name (``mask_000008_03.png`` -> 3), else the 1-based
    position in name order."""
    folder = Path(folder)
    if not folder.is_dir():
        raise SceneFileError(folder, "mask folder not found")
    files = sorted(folder.glob("*.png"))
    if not files:
        return MaskCandidates.empty(*hw)
    ids = []
    for i, f in enumerate(files):
        m = re.search(r"_(\d+)$", f.stem)
        ids.append(int(m.group(1)) if m else i + 1)
    if len(set(ids)) != len(ids):
        ids = list(range(1, len(files) + 1))
    masks = np.stack([read_mask(f, expect_hw=hw) for f in files])
    return MaskCandidates(masks, np.asarray(ids, np.int32))


def read_external_view(image: Path, masks: Path, camera: Path, depth: Path | None = None, frame: int = -1) -> View:
    cam = read_camera_json(camera)
    hw = (cam.height, cam.width)
    rgb = read_rgb(image, expect_hw=hw)
    d = read_depth_mm(depth, expect_hw=hw) if depth is not None else None
    return View(frame=frame, rgb=rgb, camera=cam, depth=d, masks=read_mask_folder(masks, hw), name=Path(image).name)
