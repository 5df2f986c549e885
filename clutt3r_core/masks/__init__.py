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

``ensure_candidates(scene, masks)`` is the one rule of where a run's candidates come from
(``pipeline.segment``, ``clutt3r segment`` and ``clutt3r bench`` all call it): ``"auto"`` keeps
the scene's own and fills views without any with the builtin generator, ``"scene"`` generates
nothing, a generator (name or object) replaces every initial view's. It returns the scene and a
``MaskProvenance`` that the run records. ``fill_masks(scene, generator)`` gives every initial view
candidates from a generator and ``write_masks(scene, folder)`` writes them in the sample layout's
naming.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol, runtime_checkable

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import MaskCandidates, Scene, View

__all__ = [
    "MaskGenerator", "MaskProvenance", "create_mask_generator", "ensure_candidates", "fill_masks",
    "write_masks", "scene_has_masks", "with_run_masks",
]


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


@dataclass(frozen=True)
class MaskProvenance:
    """Where a run's mask candidates came from (``ensure_candidates``; recorded in run.json).

    Attributes:
        generator: the generator that made candidates (a registry name, or its ``name``
            attribute), or ``"scene"`` when every initial view kept the scene's own.
        generated: frames (int) whose candidates the generator made; empty for ``"scene"``.
        frames: (V,) frames of every initial view, in the scene's order, when anything was
            generated (what ``save_run`` writes to ``RUN/instance_masks/``); empty otherwise
            and for a run read back from disk.
        candidates: the candidates of those views, aligned with ``frames`` (the very arrays of
            the scene, no copy).
        seconds: wall time of the generation (0 when nothing was generated).

    Equality compares ``generator`` and ``generated`` only (what run.json keeps), so a run read
    back equals the one written.
    """

    generator: str = "scene"
    generated: tuple[int, ...] = ()
    frames: tuple[int, ...] = field(default=(), compare=False)
    candidates: tuple[MaskCandidates, ...] = field(default=(), compare=False)
    seconds: float = field(default=0.0, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "generated", tuple(int(f) for f in self.generated))
        object.__setattr__(self, "frames", tuple(int(f) for f in self.frames))
        object.__setattr__(self, "candidates", tuple(self.candidates))
        if not isinstance(self.generator, str) or not self.generator:
            raise SceneError("MaskProvenance.generator must be a non-empty string")
        if len(self.frames) != len(self.candidates):
            raise SceneError(f"MaskProvenance: {len(self.frames)} frames but {len(self.candidates)} candidate sets")
        if self.generator == "scene" and self.generated:
            raise SceneError("MaskProvenance: generator 'scene' generated nothing")

    def to_json(self) -> dict:
        """run.json's ``masks`` entry; ``folder`` is where ``save_run`` writes the candidates."""
        return {"generator": self.generator, "folder": "instance_masks" if self.candidates else None,
                "generated": list(self.generated)}

    @classmethod
    def from_json(cls, d) -> MaskProvenance:
        if not isinstance(d, dict) or not isinstance(d.get("generator"), str) or not d["generator"]:
            raise SceneError("'masks' must be an object with a non-empty 'generator' string")
        gen = d.get("generated", [])
        if not isinstance(gen, list) or not all(isinstance(f, int) and not isinstance(f, bool) for f in gen):
            raise SceneError("'masks.generated' must be a list of frame numbers")
        return cls(generator=d["generator"], generated=tuple(gen))


def ensure_candidates(
    scene: Scene, masks: str | MaskGenerator = "auto", *, progress: bool = False
) -> tuple[Scene, MaskProvenance]:
    """The scene with candidates on its initial views, and where they came from.

    ``masks``:

    * ``"auto"`` (default; issue 11: the builtin generator is the default when a scene has no
      candidates): views that have candidates keep them, the others get the builtin's;
    * ``"scene"``: nothing is generated (``pipeline.segment`` then refuses a view without);
    * a registry name (``"builtin"``, ...) or a ``MaskGenerator``: every initial view's
      candidates are replaced by the generator's (a name is created without arguments, so
      ``import`` / ``sam-onnx`` need an object: ``create_mask_generator("import", source=...)``).

    Post-interaction views are left as they are.
    """
    if masks == "scene" or (masks == "auto" and scene_has_masks(scene)):
        return scene, MaskProvenance()
    if isinstance(masks, str):
        gen = create_mask_generator("builtin" if masks == "auto" else masks)
    elif isinstance(masks, MaskGenerator):
        gen = masks
    else:
        raise SceneError(f"masks must be 'auto', 'scene', a mask generator name or object, not {masks!r}")
    only_missing = masks == "auto"
    t0 = time.perf_counter()
    done = [v.frame for v in scene.initial_views if not (only_missing and v.masks is not None)]
    out = fill_masks(scene, gen, only_missing=only_missing, progress=progress)
    views = out.initial_views
    return out, MaskProvenance(
        generator=str(getattr(gen, "name", type(gen).__name__)), generated=tuple(done),
        frames=tuple(v.frame for v in views), candidates=tuple(v.masks for v in views),
        seconds=time.perf_counter() - t0,
    )


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
