"""The generator's types: difficulty presets, ``SynthConfig`` and the generation record.

Split from ``generator.py`` (which re-exports every name) so that the generation code and
what it is configured with / returns can be read apart.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Literal

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import Scene
from clutt3r_core.synth.masks import MaskNoiseName, mask_noise_preset
from clutt3r_core.synth.objects import spec_of
from clutt3r_core.synth.sensor import DepthNoiseName, depth_noise_preset

__all__ = ["Difficulty", "DifficultyPreset", "DIFFICULTY_PRESETS", "SynthConfig", "InteractionInfo", "SynthInfo",
           "SynthResult"]


Difficulty = Literal["easy", "intermediate", "hard"]


@dataclass(frozen=True)
class DifficultyPreset:
    """Clutter level (ours; the paper splits real sequences by mean occlusion into easy /
    intermediate / hard with mean overlap 11.6 / 19.8 / 31.7 %, Sec. IV-A).

    Attributes:
        n_objects: objects in the pile.
        pile_radius: objects are dropped over a disc of this radius, metres; smaller = denser.
        tray: whether the pile lies in a tray (floor + 4 walls) instead of on the bare table.
    """

    n_objects: int
    pile_radius: float
    tray: bool


DIFFICULTY_PRESETS: dict[str, DifficultyPreset] = {
    "easy": DifficultyPreset(6, 0.14, False),
    "intermediate": DifficultyPreset(10, 0.14, False),
    "hard": DifficultyPreset(15, 0.12, True),
}

@dataclass(frozen=True)
class SynthConfig:
    """Everything that defines a synthetic scene (with the seed, the scene is fully determined).

    Attributes:
        seed: random seed (non-negative).
        preset: clutter level, see ``DIFFICULTY_PRESETS``.
        views: number of initial views (the paper uses 8, Sec. IV-A).
        width: image width, pixels.
        height: image height, pixels.
        mask_noise: mask-candidate error model, see ``masks.MASK_NOISE_PRESETS``.
        depth_noise: depth-sensor model, see ``sensor.DEPTH_NOISE_PRESETS``.
        prepost: also simulate one interaction and render one post-interaction view.
        tray: override the preset's tray choice (None = preset).
        n_objects: override the preset's object count (None = preset).
        pile_radius: override the preset's pile radius, metres (None = preset).
        objects: explicit registry model ids to use instead of a random draw (length sets the count).
        focal_px: focal length in pixels at 640 px width; scaled with ``width`` (ours: ~ a D435 colour camera).
        distance: (min, max) camera distance to the pile centre, metres (ours: robot-arm reach).
        elevation_deg: (min, max) camera elevation above the table, degrees.
        azimuth_span_deg: the cameras spread over an arc of this many degrees around the pile.
        name: scene name; default ``synth_{preset}_{seed:04d}``.
    """

    seed: int = 0
    preset: Difficulty = "easy"
    views: int = 8
    width: int = 640
    height: int = 480
    mask_noise: MaskNoiseName = "grounded-sam-like"
    depth_noise: DepthNoiseName = "none"
    prepost: bool = False
    tray: bool | None = None
    n_objects: int | None = None
    pile_radius: float | None = None
    objects: tuple[str, ...] | None = None
    focal_px: float = 400.0
    distance: tuple[float, float] = (0.45, 0.75)
    elevation_deg: tuple[float, float] = (35.0, 70.0)
    azimuth_span_deg: float = 300.0
    name: str = ""

    def __post_init__(self) -> None:
        if self.seed < 0:
            raise SceneError(f"SynthConfig.seed must be non-negative, got {self.seed}")
        if self.preset not in DIFFICULTY_PRESETS:
            raise SceneError(f"unknown preset '{self.preset}'; choose one of {sorted(DIFFICULTY_PRESETS)}")
        mask_noise_preset(self.mask_noise)
        depth_noise_preset(self.depth_noise)
        if not 1 <= self.views <= 64:
            raise SceneError(f"SynthConfig.views must be in 1..64, got {self.views}")
        if self.width < 16 or self.height < 16:
            raise SceneError(f"image size {self.width}x{self.height} is too small (at least 16x16)")
        if self.n_objects is not None and not 1 <= self.n_objects <= 60:
            raise SceneError(f"SynthConfig.n_objects must be in 1..60, got {self.n_objects}")
        if self.objects is not None:
            object.__setattr__(self, "objects", tuple(self.objects))
            for k in self.objects:
                spec_of(k)
            if not self.objects:
                raise SceneError("SynthConfig.objects must not be empty")
        lo, hi = self.distance
        if not 0.1 <= lo <= hi:
            raise SceneError(f"SynthConfig.distance must satisfy 0.1 <= min <= max, got {self.distance}")
        elo, ehi = self.elevation_deg
        if not 5 <= elo <= ehi <= 89:
            raise SceneError(f"SynthConfig.elevation_deg must lie in [5, 89], got {self.elevation_deg}")

    @property
    def difficulty(self) -> DifficultyPreset:
        return DIFFICULTY_PRESETS[self.preset]

    @property
    def object_count(self) -> int:
        if self.objects is not None:
            return len(self.objects)
        return self.n_objects if self.n_objects is not None else self.difficulty.n_objects

    @property
    def use_tray(self) -> bool:
        return self.difficulty.tray if self.tray is None else bool(self.tray)

    @property
    def radius(self) -> float:
        return self.pile_radius if self.pile_radius is not None else self.difficulty.pile_radius

    @property
    def scene_name(self) -> str:
        return self.name or f"synth_{self.preset}_{self.seed:04d}"

    @property
    def K(self) -> np.ndarray:
        f = self.focal_px * self.width / 640.0
        return np.array([[f, 0.0, (self.width - 1) / 2.0], [0.0, f, (self.height - 1) / 2.0], [0.0, 0.0, 1.0]])


@dataclass(frozen=True, eq=False)
class InteractionInfo:
    """The simulated interaction between the initial views and the post-interaction view.

    Attributes:
        post_frame: frame index of the post-interaction view.
        removed_object: ground-truth id of the grasped (removed) object.
        displaced_object: ground-truth id of the pushed object.
        T_new_old: (4, 4) world-frame rigid motion of the displaced object:
            ``T_world_object_post = T_new_old @ T_world_object_initial``.
        T_world_object_post: (4, 4) pose of the displaced object after the interaction.
    """

    post_frame: int
    removed_object: int
    displaced_object: int
    T_new_old: np.ndarray
    T_world_object_post: np.ndarray

    def to_json(self) -> dict:
        return {"schema_version": 1, "post_frame": self.post_frame, "removed_object": self.removed_object,
                "displaced_object": self.displaced_object, "T_new_old": self.T_new_old.tolist(),
                "T_world_object_post": self.T_world_object_post.tolist(),
                "convention": "T_world_object_post = T_new_old @ T_world_object_initial (world-frame motion)"}


@dataclass(frozen=True, eq=False)
class SynthInfo:
    """The generation record of a scene (what is not in the Scene itself).

    Attributes:
        config: the configuration.
        object_keys: registry model id of every ground-truth object (== ObjectInfo.name).
        frames: frame index of every initial view (column order of ``occlusion``).
        occlusion: (K, V) float64 fraction of each object's full silhouette hidden by other
            objects or the tray in each initial view; NaN where the object is out of frame.
        mean_occlusion: mean of ``occlusion`` over finite entries (the benchmark split key).
        centre: (3,) world pile centre on the table, metres.
        mask_kinds: frame -> kind of every candidate (aligned with ``View.masks.ids``).
        mask_sources: frame -> object ids each candidate was made from.
        interaction: the interaction, or None without ``prepost``.
        seconds: wall time per stage (physics, render, masks, points, prepost, total);
            not written to disk so files stay byte-identical for a seed.
    """

    config: SynthConfig
    object_keys: tuple[str, ...]
    frames: tuple[int, ...]
    occlusion: np.ndarray
    mean_occlusion: float
    centre: np.ndarray
    mask_kinds: dict[int, tuple[str, ...]]
    mask_sources: dict[int, tuple[tuple[int, ...], ...]]
    interaction: InteractionInfo | None = None
    seconds: dict[str, float] = field(default_factory=dict)

    def to_json(self) -> dict:
        cfg = asdict(self.config)
        return {
            "schema_version": 1,
            "config": cfg,
            "object_keys": list(self.object_keys),
            "frames": list(self.frames),
            "occlusion": [[None if not np.isfinite(x) else round(float(x), 6) for x in row] for row in self.occlusion],
            "mean_occlusion": round(float(self.mean_occlusion), 6),
            "centre": [float(c) for c in self.centre],
            "masks": {str(f): [{"kind": k, "sources": list(s)} for k, s in zip(self.mask_kinds[f], self.mask_sources[f])]
                      for f in sorted(self.mask_kinds)},
        }

    @staticmethod
    def from_json(meta: dict, interaction: dict | None = None) -> "SynthInfo":
        """Inverse of ``to_json`` (timings are not stored, so ``seconds`` is empty)."""
        cfg = dict(meta["config"])
        for k in ("distance", "elevation_deg", "objects"):
            if cfg.get(k) is not None:
                cfg[k] = tuple(cfg[k])
        inter = None
        if interaction is not None:
            inter = InteractionInfo(int(interaction["post_frame"]), int(interaction["removed_object"]),
                                    int(interaction["displaced_object"]), np.asarray(interaction["T_new_old"], float),
                                    np.asarray(interaction["T_world_object_post"], float))
        masks = meta.get("masks", {})
        return SynthInfo(
            config=SynthConfig(**cfg),
            object_keys=tuple(meta["object_keys"]),
            frames=tuple(int(f) for f in meta["frames"]),
            occlusion=np.array([[np.nan if x is None else x for x in row] for row in meta["occlusion"]], float)
            .reshape(len(meta["object_keys"]), len(meta["frames"])),
            mean_occlusion=float(meta["mean_occlusion"]),
            centre=np.asarray(meta["centre"], float),
            mask_kinds={int(f): tuple(m["kind"] for m in ms) for f, ms in masks.items()},
            mask_sources={int(f): tuple(tuple(m["sources"]) for m in ms) for f, ms in masks.items()},
            interaction=inter,
        )


@dataclass(frozen=True, eq=False)
class SynthResult:
    scene: Scene
    info: SynthInfo
