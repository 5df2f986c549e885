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
from clutt3r_core.segmentation.instance_surface import InstanceSurfaceConfig
from clutt3r_core.segmentation.refine import RefineConfig
from clutt3r_core.segmentation.trees import TreeConfig
from clutt3r_core.segmentation.unvoted import UnvotedConfig
from clutt3r_core.segmentation.vote import VoteConfig
from clutt3r_core.supervoxels import SuperVoxelConfig

__all__ = [
    "SegmentConfig",
    "PRESETS",
    "Addition",
    "ADDITIONS",
    "with_fields",
    "ours_without",
    "paper_with",
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
    refine: RefineConfig = field(default_factory=RefineConfig)
    """Post-vote fragment absorption (ours, issue 13; ``segmentation.refine``)."""
    instance_surface: InstanceSurfaceConfig = field(default_factory=InstanceSurfaceConfig)
    """Each instance's points onto a local surface of its own points, after the labelling (ours,
    issue 13; off by default: ``segmentation.instance_surface``, docs/benchmark/strict-iou.md)."""
    unvoted: UnvotedConfig = field(default_factory=UnvotedConfig)
    """Unlabelled clusters above the support become low-confidence instances (ours, session 8; off
    by default: ``segmentation.unvoted``, docs/benchmark/strict-iou.md)."""
    embedder: str = "appearance-hsv"
    """Backend of S_semantic (Sec. III-B.2 uses Duoduo CLIP; see clutt3r_core/embeddings.py)."""
    background_fraction: float = 0.5
    """Ours: a mask whose 3D points lie more than this fraction on support super-voxels
    (table, tray) is background: it stays in its tree but never joins a group
    (``segmentation.evidence.background_masks``)."""
    exclude_background_masks: bool = True
    """Ours (findings point 4): flag background masks (``background_fraction``, or no 3D point
    at all) and keep them out of the leaf graph, the groups and substitution. False = the
    paper's text: every leaf is a candidate."""


# ------------------------------------------------------------------ our additions and the paper


@dataclass(frozen=True)
class Addition:
    """One rule of ours over the paper's text (Sec. III, IV), as the config fields that switch it.

    ``fields``: (dotted field path in ``SegmentConfig``, value in ``ours``, value in ``paper``).
    ``ours`` = ``SegmentConfig()``; ``paper`` = every addition at its paper value. The
    leave-one-out ablation (``evaluation.methods``) sets one addition's fields to the paper's
    value in ``ours`` (``ours_without``) or to ours in ``paper`` (``paper_with``).
    """

    key: str
    """Short name (benchmark method names: ``ours-no-<key>``, ``paper-with-<key>``)."""
    what: str
    """One line: what the rule does."""
    fields: tuple[tuple[str, Any, Any], ...]
    needs: tuple[str, ...] = ()
    """Keys of the additions this one reads (the support flags): ``paper_with`` switches them on
    too, since without them this one has nothing to act on."""


ADDITIONS: tuple[Addition, ...] = (
    Addition("support", "mark support super-voxels (table, tray floor, walls): RANSAC planes + extent",
             (("supervoxels.support_removal", True, False),)),
    Addition("support-not-in-spatial", "S_spatial (eq. 2) ignores support super-voxels",
             (("grouping.spatial_excludes_support", True, False),), needs=("support",)),
    Addition("support-unlabelled", "the vote never labels support super-voxels",
             (("vote.label_support", False, True),), needs=("support",)),
    Addition("background-masks", "masks mostly on support (or without 3D points) are never grouped",
             (("exclude_background_masks", True, False),), needs=("support",)),
    Addition("visible-occupancy", "o_i(k) over the part of super-voxel k that mask i's view sees",
             (("occupancy.normalise", "visible", "all"),)),
    Addition("one-mask-per-view", "a group holds at most one mask per view",
             (("grouping.one_mask_per_view", True, False),)),
    Addition("duplicate-masks", "masks of one view with pixel IoU >= 0.9 are one mask: leaf copies start as one group, "
             "a leaf copy of a parent is no candidate",
             (("grouping.duplicate_iou", 0.9, 0.0),)),
    Addition("overlap-gate", "stage 2 only merges groups that share a super-voxel (mean S_spatial > 0)",
             (("grouping.semantic_needs_overlap", True, False),)),
    Addition("overlap-gate-min", "stage 2 only merges groups whose mean S_spatial is at least 0.01 (not a stray "
             "mask edge on a shared super-voxel)",
             (("grouping.semantic_min_spatial", 0.01, 0.0),), needs=("overlap-gate",)),
    Addition("coverage-guard", "a super-voxel goes to its winner only if one of its masks covers >= 50 % of it",
             (("vote.min_coverage", 0.5, 0.0),)),
    Addition("abs-normal-dot", "|<n_i, n_j>| instead of <n_i, n_j> in eq. 1",
             (("supervoxels.absolute_normal_dot", True, False),)),
    Addition("containment-tolerance", "a mask is contained in another when >= 85 % of its pixels are (not 100 %)",
             (("trees.tau_contain", 0.85, 1.0),)),
    Addition("min-mask-area", "masks under 0.01 % of the image are dropped before the trees",
             (("trees.min_area_px", 0, 1),)),
    Addition("min-instance-points", "instances under 30 raw points are dropped",
             (("vote.min_instance_points", 30, 0),)),
    Addition("absorb-fragments", "an instance that won < 20 % of its masks' footprint and holds < 10 % of the points of "
             "the instance that won most of it is merged into that instance",
             (("refine.min_won_fraction", 0.2, 0.0),)),
    Addition("span-masks", "a mask covering >= 50 % of another instance's footprint, unconfirmed there by its own "
             "group (masks from >= half of the views), does not vote there; only instances take what it leaves",
             (("vote.span_cover", 0.5, 0.0),)),
    Addition("pixel-stride", "1080p views are sampled every 3rd pixel before voxelisation (none at 640x480)",
             (("pointcloud.pixel_stride", 0, 1),)),
    Addition("surface-estimate", "when the views' depths disagree by >= 1 mm (sensor noise, measured from the data), "
             "the raw points are moved onto the views' TSDF consensus surface before voxelisation",
             (("pointcloud.surface", "auto", "voxel-mean"),)),
    Addition("rim-attach", "with the surface estimate, lone unmoved points next to kept voxels (object rims) are kept "
             "apart and take the majority label of their 6 nearest segmented voxels after the vote",
             (("pointcloud.surface_rim_neighbours", 1, 0),)),
    Addition("planar-tops", "a super-voxel only the planar-patch support rule marked is an object's top when object "
             "masks cover it in >= 50 % of the views that see it (>= 2): un-marked, its masks re-admitted (the "
             "edges between the masks admitted before keep their S_spatial)",
             (("supervoxels.planar_mask_views", 0.5, 0.0),), needs=("support",)),
    Addition("table-contact", "with the surface estimate, object points under 2 mm above the support measured around "
             "the object are left unlabelled (the update and the grasp target read the labels before it)",
             (("refine.contact_height", 0.002, 0.0),)),
)
"""Every rule of ours over the paper's explicit text that changes a result, with its switch.
Choices the text leaves open (and that both presets share) are listed in docs/paper_choices.md."""


def with_fields(cfg: SegmentConfig, values: dict[str, Any]) -> SegmentConfig:
    """``cfg`` with the fields named by dotted paths (``"vote.min_coverage"``) replaced."""
    for path, value in values.items():
        head, _, rest = path.partition(".")
        if not hasattr(cfg, head):
            raise KeyError(f"SegmentConfig has no field '{path}'")
        if rest:
            sub = getattr(cfg, head)
            if not hasattr(sub, rest):
                raise KeyError(f"SegmentConfig has no field '{path}'")
            cfg = dataclasses.replace(cfg, **{head: dataclasses.replace(sub, **{rest: value})})
        else:
            cfg = dataclasses.replace(cfg, **{head: value})
    return cfg


def _addition(key: str) -> Addition:
    for a in ADDITIONS:
        if a.key == key:
            return a
    raise KeyError(f"no addition '{key}'; known: {', '.join(a.key for a in ADDITIONS)}")


def ours_without(key: str) -> SegmentConfig:
    """``ours`` with one addition switched off (set to the paper's value)."""
    return with_fields(SegmentConfig(), {f: paper for f, _, paper in _addition(key).fields})


def paper_with(key: str) -> SegmentConfig:
    """``paper`` with one addition switched on (set to ours), and the ones it ``needs``.

    Support marking alone (``support``) changes nothing in ``paper``: its effects are the
    rules that read the flags, each of which comes with the marking here."""
    keys = [key, *_addition(key).needs]
    return with_fields(_paper_literal(), {f: ours for k in keys for f, ours, _ in _addition(k).fields})


def _paper_literal() -> SegmentConfig:
    """The paper's text wherever it is explicit: ``ours`` with every ``ADDITIONS`` entry off.

    The paper's own values (Sec. IV: 5 mm voxels, m = 3, alpha, beta, tau_merge, tau_spat,
    tau_sem; Sec. III-B.3: one substitution round) are the defaults of both presets; what the
    text leaves open is shared with ``ours`` and listed in docs/paper_choices.md.
    """
    return with_fields(SegmentConfig(), {f: paper for a in ADDITIONS for f, _, paper in a.fields})


PresetName = Literal["default", "paper", "no-spatial", "no-substitution", "noisy-depth"]

PRESETS: dict[str, SegmentConfig] = {
    "default": SegmentConfig(),
    "paper": _paper_literal(),
    "no-spatial": SegmentConfig(grouping=GroupingConfig(use_spatial=False)),
    "no-substitution": SegmentConfig(grouping=GroupingConfig(substitution=False)),
    # ours with the multi-view surface estimate always on (clutt3r_core/surface.py), whatever the
    # depth's measured noise; ours ("auto") runs it only when the views disagree by >= 1 mm
    # (every real and RealSense-like depth measured), so the two differ on clean depth only
    # (docs/benchmark/strict-iou.md)
    "noisy-depth": SegmentConfig(pointcloud=PointCloudConfig(surface="tsdf")),
}
assert set(PRESETS) == set(get_args(PresetName))


# ------------------------------------------------------------------ JSON form


def config_to_json(cfg: Any) -> dict:
    """A (nested) config dataclass as JSON-able data: ``dataclasses.asdict`` (fields are plain scalars)."""
    return dataclasses.asdict(cfg)


ADDED_AFTER_V1: dict[str, Any] = {
    "exclude_background_masks": True,
    "grouping.spatial_excludes_support": True,
    "grouping.substitute_stranded_parents": False,
    "grouping.semantic_min_spatial": 0.0,
    "vote.revote_dropped": False,
    "vote.smooth_max_size": 0,
    "vote.smooth_k": 10,
    "vote.smooth_min_agree": 6,
    "vote.smooth_radius": 0.015,
    "vote.span_cover": 0.0,
    "vote.span_confirm": 0.5,
    "vote.span_occupancy": 0.5,
    "vote.span_instances_only": False,
    "vote.span_min_views": 0.0,
    "vote.span_confirm_apart": 0.0,
    "vote.span_before_absorb": False,
    "refine.min_won_fraction": 0.0,
    "refine.absorb_min_semantic": 0.0,
    "refine.weak_echo_ratio": 0.0,
    "refine.contact_height": 0.0,
    "instance_surface.radius": 0.0,
    "refine.contact_fill_low": 0.0,
    "refine.contact_fill_high": 0.0,
    "refine.contact_fill_distance": 0.0075,
    "refine.contact_max_noise": 0.005,
    "refine.contact_fill_mask_share": 0.0,
    "refine.contact_fill_mask_depth": 0.005,
    "refine.contact_fill_mask_margin": 0,
    "grouping.duplicate_iou": 0.0,
    "pointcloud.surface": "voxel-mean",
    "pointcloud.surface_min_points": 2,
    "pointcloud.surface_auto_sigma": 0.001,
    "pointcloud.surface_rim_neighbours": 0,
    "pointcloud.surface_rim_attach_k": 0,
    "pointcloud.surface_rim_attach_distance": 0.02,
    "pointcloud.surface_rim_moved": 0,
    "pointcloud.surface_rim_reach": 0.0,
    "unvoted.min_points": 0,
    "supervoxels.planar_mask_views": 0.0,
    "grouping.reunion_max_contain": 1.0,
    "grouping.reunion_min_semantic": -1.0,
}
"""Fields added after trace version 1, each with the value that reproduces the code that wrote
such a trace (issue 13: the first two only made existing rules switchable; the others are
fixes or rules that the old code did not have). Only these may be missing from a stored config."""


_STAGES_ADDED_AFTER_V1 = ("refine", "instance_surface", "unvoted")
"""Whole stage configs added after trace version 1 (issue 13: ``refine``); a config without one
gets its defaults with the ``ADDED_AFTER_V1`` fields (any other missing stage is an error)."""


def config_from_json(data: Any, file: str | Path) -> SegmentConfig:
    """The ``SegmentConfig`` written by ``config_to_json``; ``SceneFileError(file, ...)`` naming the
    offending field when ``data`` does not match the current fields exactly (except the fields
    of ``ADDED_AFTER_V1``, which a config written before them gets as the old code behaved)."""
    if isinstance(data, dict):
        data = _fill_added(data)
    return dataclass_from_json(SegmentConfig, data, file, "config")


def _fill_added(data: dict) -> dict:
    out = dict(data)
    for path, value in ADDED_AFTER_V1.items():
        head, _, rest = path.partition(".")
        if not rest:
            out.setdefault(head, value)
        elif head not in out and head in _STAGES_ADDED_AFTER_V1:  # its defaults, this field as the old code behaved
            out[head] = {**dataclasses.asdict(getattr(SegmentConfig(), head)),
                         **{p.partition(".")[2]: v for p, v in ADDED_AFTER_V1.items() if p.startswith(head + ".")}}
        elif isinstance(out.get(head), dict) and rest not in out[head]:
            out[head] = {**out[head], rest: value}
    return out


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
