"""Scene readers and writers: the sample layout and BOP scene folders.

``load_scene`` picks the reader from the files in the folder.
"""

from __future__ import annotations

from pathlib import Path

from clutt3r_core.errors import SceneFileError
from clutt3r_core.io.bop import load_bop_scene
from clutt3r_core.io.sample_layout import load_sample_layout, write_sample_layout
from clutt3r_core.scene import Scene

__all__ = ["load_scene", "load_sample_layout", "write_sample_layout", "load_bop_scene"]


def load_scene(path: str | Path, *, load_gt: bool = True) -> Scene:
    """Load a scene folder, detecting its layout.

    ``transforms.json`` -> sample layout; ``scene_camera.json`` -> BOP (default
    options). ``path`` may also be one of those two files, or a release sample folder
    whose scene is in ``data/``. Raises SceneFileError naming the folder otherwise.

    ``load_gt=False`` leaves the ground truth unread (``Scene.ground_truth`` None): what a
    segmentation needs (``clutt3r segment`` never reads it; a generated 640x480 scene's
    instance maps and labelled points cost ~0.05 s of CPU, a BOP scene's visible masks and
    back-projection far more; issue 13).
    """
    p = Path(path)
    if p.is_file() and p.name in ("transforms.json", "scene_camera.json"):
        p = p.parent
    if not p.is_dir():
        raise SceneFileError(p, "scene folder not found")
    if (p / "transforms.json").is_file():
        return load_sample_layout(p, load_gt=load_gt)
    if (p / "scene_camera.json").is_file():
        return load_bop_scene(p, load_gt=load_gt)
    if (p / "data" / "transforms.json").is_file():  # the original release's samples/<name>/data
        return load_sample_layout(p / "data", load_gt=load_gt)
    raise SceneFileError(
        p, "not a scene folder: found neither transforms.json (sample layout) nor scene_camera.json (BOP)"
    )
