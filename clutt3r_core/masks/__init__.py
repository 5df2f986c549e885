"""Mask candidates per view: the ``MaskGenerator`` backend kind (registry kind ``mask_generator``).

The method needs noisy, overlapping, hierarchical candidates per view (the paper prompts
Grounded SAM with "object"). A generator turns one posed RGB-D view into
``MaskCandidates``; the pipeline builds each view's containment tree from them.

Generators (registered in ``clutt3r_core/registry.py``):

* ``builtin`` (``masks/builtin.py``): multi-scale RGB-D segmentation, no weights; the
  default when a scene has no candidates.
* ``import`` (``masks/imported.py``): candidates from files (PNG folder, npz, COCO RLE JSON;
  ``masks/formats.py``).
* ``sam-onnx`` (``masks/sam_onnx.py``): SAM-family encoder/decoder exported to ONNX, from
  local paths.

``fill_masks(scene, generator)`` gives every initial view candidates from a generator and
``write_masks(scene, folder)`` writes them in the sample layout's naming.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Protocol, runtime_checkable

from clutt3r_core.scene import MaskCandidates, Scene, View

__all__ = ["MaskGenerator", "create_mask_generator", "fill_masks", "write_masks", "scene_has_masks", "with_run_masks"]


@runtime_checkable
class MaskGenerator(Protocol):
    """Makes mask candidates for one view."""

    name: str

    def generate(self, view: View) -> MaskCandidates:
        """-> candidates of the view's image size (unique ids, 1..M by convention of the
        sample layout; any overlap allowed)."""
        ...


def create_mask_generator(name: str = "builtin", **kwargs) -> MaskGenerator:
    """A registered mask generator by name (``clutt3r_core.registry``)."""
    from clutt3r_core.registry import create_backend

    return create_backend("mask_generator", name, **kwargs)


def scene_has_masks(scene: Scene) -> bool:
    """True when every initial view carries mask candidates (possibly zero of them)."""
    return all(v.masks is not None for v in scene.initial_views)


def fill_masks(scene: Scene, generator: MaskGenerator, *, only_missing: bool = False,
               progress: bool = False) -> Scene:
    """A copy of ``scene`` whose initial views carry ``generator``'s candidates.

    ``only_missing`` keeps views that already have candidates. Post-interaction views are
    left as they are.
    """
    views = list(scene.views)
    todo = [i for i in scene.initial if not (only_missing and views[i].masks is not None)]
    it = todo
    if progress and todo:
        from tqdm import tqdm

        it = tqdm(todo, desc=f"masks ({generator.name})", unit="view", leave=False)
    for i in it:
        views[i] = dataclasses.replace(views[i], masks=generator.generate(views[i]))
    return dataclasses.replace(scene, views=tuple(views))


def write_masks(scene: Scene, folder: str | Path, *, views: str = "initial") -> list[Path]:
    """Write the candidates of the scene's initial (or ``"all"``) views into ``folder`` as
    ``mask_{frame:06d}_{id:02d}.png`` (the sample layout; ids of 100 and more get 3 digits,
    which the loader reads)."""
    from clutt3r_core.masks.formats import write_png_masks

    chosen = scene.initial_views if views == "initial" else scene.views
    out: list[Path] = []
    for v in chosen:
        if v.masks is not None:
            out += write_png_masks(folder, v.frame, v.masks)
    return out


def with_run_masks(scene: Scene, run_dir: str | Path) -> Scene:
    """The scene with the candidates a run was made from: when ``RUN/instance_masks/`` exists
    (generated candidates, written by ``clutt3r segment``), they replace the scene's own on the
    initial views, so a viewer shows what the run's trace refers to. Unchanged otherwise."""
    from clutt3r_core.masks.formats import read_png_masks

    folder = Path(run_dir) / "instance_masks"
    if not folder.is_dir():
        return scene
    views = list(scene.views)
    for i in scene.initial:
        v = views[i]
        views[i] = dataclasses.replace(v, masks=read_png_masks(folder, v.frame, (v.camera.height, v.camera.width)))
    return dataclasses.replace(scene, views=tuple(views))
