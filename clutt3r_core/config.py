"""The segmentation core's typed configuration and its presets, and their JSON form.

``SegmentConfig`` holds one frozen config per stage. A run's trace stores it as JSON
(``config_to_json``) and reads it back EQUAL (``config_from_json``): the reader is strict,
so an unknown or missing field, or a value of the wrong type, is an error naming the
file and the field, never a silent fall-back to defaults (a replay with the wrong vote
settings would show a run that never happened).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, TypeVar, Union, get_args, get_origin, get_type_hints

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.occupancy import OccupancyConfig
from clutt3r_core.pointcloud import PointCloudConfig
from clutt3r_core.segmentation.grouping import GroupingConfig
from clutt3r_core.segmentation.trees import TreeConfig
from clutt3r_core.segmentation.vote import VoteConfig
from clutt3r_core.supervoxels import SuperVoxelConfig

__all__ = [
    "SegmentConfig",
    "PRESETS",
    "PresetName",
    "config_to_json",
    "config_from_json",
    "dataclass_from_json",
]


@dataclass(frozen=True)
class SegmentConfig:
    """All stages of the segmentation core; each field is one stage's config."""

    pointcloud: PointCloudConfig = field(default_factory=PointCloudConfig)
    supervoxels: SuperVoxelConfig = field(default_factory=SuperVoxelConfig)
    occupancy: OccupancyConfig = field(default_factory=OccupancyConfig)
    trees: TreeConfig = field(default_factory=TreeConfig)
    grouping: GroupingConfig = field(default_factory=GroupingConfig)
    vote: VoteConfig = field(default_factory=VoteConfig)
    embedder: str = "appearance-hsv"
    """Backend of S_semantic (Sec. III-B.2 uses Duoduo CLIP; see clutt3r_core/embeddings.py)."""
    background_fraction: float = 0.5
    """Ours: a mask whose 3D points lie more than this fraction on support super-voxels
    (table, tray) is background: it stays in its tree but never joins a group
    (``segmentation.background.background_masks``)."""


def _paper_literal() -> SegmentConfig:
    # The paper's text without our additions: occupancy over all voxels of a super-voxel,
    # no coverage guard, no support handling in the vote, no overlap gate on stage 2.
    return SegmentConfig(
        occupancy=OccupancyConfig(normalise="all"),
        grouping=GroupingConfig(semantic_needs_overlap=False),
        vote=VoteConfig(min_coverage=0.0, label_support=True),
    )


PresetName = Literal["default", "paper", "no-spatial", "no-substitution"]

PRESETS: dict[str, SegmentConfig] = {
    "default": SegmentConfig(),
    "paper": _paper_literal(),
    "no-spatial": SegmentConfig(grouping=GroupingConfig(use_spatial=False)),
    "no-substitution": SegmentConfig(grouping=GroupingConfig(substitution=False)),
}
assert set(PRESETS) == set(get_args(PresetName))


# ------------------------------------------------------------------ JSON form


def config_to_json(cfg: Any) -> dict:
    """A (nested) config dataclass as JSON-able data: ``dataclasses.asdict`` (fields are plain scalars)."""
    return dataclasses.asdict(cfg)


def config_from_json(data: Any, file: str | Path) -> SegmentConfig:
    """The ``SegmentConfig`` written by ``config_to_json``; ``SceneFileError(file, ...)`` naming the
    offending field when ``data`` does not match the current fields exactly."""
    return dataclass_from_json(SegmentConfig, data, file, "config")


T = TypeVar("T")


def dataclass_from_json(cls: type[T], data: Any, file: str | Path, where: str) -> T:
    """Build dataclass ``cls`` from JSON ``data`` strictly (no unknown, no missing fields, exact types).

    ``where`` is the dotted path of ``data`` inside the file, used in the error message.
    Supported field types: bool, int, float (an int is accepted), str, Literal, None unions,
    tuples and nested dataclasses.
    """
    if not isinstance(data, dict):
        raise SceneFileError(file, f"{where}: expected an object, got {type(data).__name__}")
    hints = get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    unknown = sorted(set(data) - set(names))
    if unknown:
        raise SceneFileError(file, f"{where}.{unknown[0]}: unknown field (written by another version?)")
    missing = [n for n in names if n not in data]
    if missing:
        raise SceneFileError(file, f"{where}.{missing[0]}: missing field (written by another version?)")
    kwargs = {n: _value(hints[n], data[n], file, f"{where}.{n}") for n in names}
    try:
        return cls(**kwargs)
    except SceneError as e:  # a config's own range checks (__post_init__)
        raise SceneFileError(file, f"{where}: {e}") from None


def _value(tp: Any, v: Any, file: str | Path, where: str) -> Any:
    origin = get_origin(tp)
    if dataclasses.is_dataclass(tp):
        return dataclass_from_json(tp, v, file, where)
    if origin is Literal:
        if not any(type(v) is type(a) and v == a for a in get_args(tp)):
            raise SceneFileError(file, f"{where}: {v!r} is not one of {list(get_args(tp))}")
        return v
    if origin in (Union, types.UnionType):
        args = get_args(tp)
        if v is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _value(a, v, file, where)
            except SceneFileError as e:
                errors.append(e.problem)
        raise SceneFileError(file, errors[0] if errors else f"{where}: unexpected null")
    if origin is tuple:
        if not isinstance(v, list):
            raise SceneFileError(file, f"{where}: expected a list, got {type(v).__name__}")
        args = get_args(tp)
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_value(args[0], x, file, f"{where}[{i}]") for i, x in enumerate(v))
        if len(args) != len(v):
            raise SceneFileError(file, f"{where}: expected {len(args)} items, got {len(v)}")
        return tuple(_value(a, x, file, f"{where}[{i}]") for i, (a, x) in enumerate(zip(args, v)))
    if tp is bool:
        if not isinstance(v, bool):
            raise SceneFileError(file, f"{where}: expected true/false, got {v!r}")
        return v
    if tp is int:
        if isinstance(v, bool) or not isinstance(v, int):
            raise SceneFileError(file, f"{where}: expected an integer, got {v!r}")
        return v
    if tp is float:
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise SceneFileError(file, f"{where}: expected a number, got {v!r}")
        return float(v)
    if tp is str:
        if not isinstance(v, str):
            raise SceneFileError(file, f"{where}: expected a string, got {v!r}")
        return v
    if tp is typing.Any:
        return v
    raise SceneFileError(file, f"{where}: field type {tp} cannot be read from JSON")
