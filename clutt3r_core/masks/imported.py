"""The ``import`` mask generator: candidates read from files a user already has.

``ImportMaskGenerator(source)`` reads, for each view, from ``source``:

* a folder of ``mask_{frame:06d}_{id:02d}.png`` (the sample layout's ``instance_masks/``);
* a folder of per-view ``.npz`` or ``.json`` files, matched to a view by the last number in
  the file name (``masks_000003.npz``, ``image_000003.json``);
* one COCO JSON file with ``images`` / ``annotations`` for every view (matched by
  ``image_id`` = frame, or by the image's ``file_name``).

Formats and their checks: ``clutt3r_core.masks.formats``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from clutt3r_core.errors import SceneFileError
from clutt3r_core.masks.formats import frame_of, read_coco_masks, read_npz_masks, read_png_masks
from clutt3r_core.scene import MaskCandidates, View

__all__ = ["ImportMaskGenerator", "ImportFormat"]

ImportFormat = Literal["auto", "png", "npz", "coco"]


def _detect(source: Path) -> str:
    if source.is_file():
        if source.suffix.lower() == ".json":
            return "coco"
        if source.suffix.lower() == ".npz":
            return "npz"
        raise SceneFileError(source, "mask source must be a folder, a .json (COCO RLE) or a .npz file")
    if not source.is_dir():
        raise SceneFileError(source, "mask source not found")
    names = [p.name for p in source.iterdir()]
    if any(n.startswith("mask_") and n.endswith(".png") for n in names):
        return "png"
    if any(n.endswith(".npz") for n in names):
        return "npz"
    if any(n.endswith(".json") for n in names):
        return "coco"
    raise SceneFileError(source, "no mask files found (expected mask_FFFFFF_MM.png, per-view .npz or .json)")


class ImportMaskGenerator:
    """``MaskGenerator`` ``import``: see the module docstring.

    Args:
        source: a folder or file (module docstring); required.
        format: ``auto`` picks from the files found.
    """

    name = "import"

    def __init__(self, source: str | Path | None = None, format: ImportFormat = "auto") -> None:
        if source is None:
            raise SceneFileError(Path("."), "the import mask generator needs a source (--mask-source PATH)")
        self.source = Path(source)
        self.format = _detect(self.source) if format == "auto" else format

    def _per_view_file(self, view: View, suffix: str) -> Path:
        hits = [p for p in sorted(self.source.iterdir()) if p.suffix.lower() == suffix and frame_of(p) == view.frame]
        if not hits:
            raise SceneFileError(
                self.source, f"no {suffix} mask file for frame {view.frame} (a name ending in {view.frame:06d}{suffix})"
            )
        if len(hits) > 1:
            raise SceneFileError(self.source, f"several {suffix} files for frame {view.frame}: {[p.name for p in hits]}")
        return hits[0]

    def generate(self, view: View) -> MaskCandidates:
        hw = (view.camera.height, view.camera.width)
        if self.format == "png":
            return read_png_masks(self.source, view.frame, hw)
        if self.format == "npz":
            path = self.source if self.source.is_file() else self._per_view_file(view, ".npz")
            return read_npz_masks(path, hw)
        if self.format == "coco":
            if self.source.is_file():
                return read_coco_masks(self.source, hw, frame=view.frame, image_name=view.name or None)
            return read_coco_masks(self._per_view_file(view, ".json"), hw)
        raise SceneFileError(self.source, f"unknown mask format '{self.format}' (auto, png, npz, coco)")
