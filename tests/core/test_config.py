"""The run's typed config: saved in the trace as JSON and read back equal, or refused naming the field."""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.config import (
    ADDED_AFTER_V1,
    ADDITIONS,
    PRESETS,
    SegmentConfig,
    config_from_json,
    config_to_json,
    ours_without,
    paper_with,
    with_fields,
)
from clutt3r_core.errors import SceneFileError
from clutt3r_core.occupancy import OccupancyConfig
from clutt3r_core.pointcloud import PointCloudConfig
from clutt3r_core.segmentation.grouping import GroupingConfig
from clutt3r_core.segmentation.trace import load_trace, save_trace
from clutt3r_core.segmentation.vote import VoteConfig

from ._tiny_run import tiny_segmentation

_V1_CONFIG = Path(__file__).parent / "data" / "trace_v1_default_config.json"


def test_pipeline_re_exports_the_config():
    from clutt3r_core import pipeline

    assert pipeline.SegmentConfig is SegmentConfig and pipeline.PRESETS is PRESETS


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_round_trips_through_a_saved_trace(name, tmp_path):
    cfg = PRESETS[name]
    tr = replace(tiny_segmentation().trace, config=cfg)
    save_trace(tr, tmp_path / "trace")
    back = load_trace(tmp_path / "trace").config
    assert isinstance(back, SegmentConfig)
    assert back == cfg
    assert type(back.vote) is VoteConfig and back.vote == cfg.vote


def test_the_segmentation_trace_carries_its_typed_config():
    seg = tiny_segmentation()
    assert seg.trace.config == SegmentConfig()


@settings(max_examples=60, deadline=None)
@given(
    voxel=st.floats(1e-4, 0.1, allow_nan=False),
    tau_spat=st.floats(0.0, 1.0, allow_nan=False),
    min_cov=st.floats(0.0, 1.0, allow_nan=False),
    min_pts=st.integers(0, 10_000),
    bg=st.floats(0.0, 1.0, allow_nan=False),
    normalise=st.sampled_from(["visible", "all"]),
    label_support=st.booleans(),
)
def test_json_round_trip_is_exact(voxel, tau_spat, min_cov, min_pts, bg, normalise, label_support):
    cfg = SegmentConfig(
        pointcloud=PointCloudConfig(voxel_size=voxel),
        occupancy=OccupancyConfig(normalise=normalise),
        grouping=GroupingConfig(tau_spat=tau_spat),
        vote=VoteConfig(min_coverage=min_cov, min_instance_points=min_pts, label_support=label_support),
        background_fraction=bg,
    )
    text = json.dumps(config_to_json(cfg))  # through text, as in trace.json
    assert config_from_json(json.loads(text), "trace.json") == cfg


def test_a_version_1_trace_config_still_loads(tmp_path):
    # trace.json "config" exactly as version 1 wrote it (pipeline._jsonable(asdict(SegmentConfig())))
    folder = save_trace(tiny_segmentation().trace, tmp_path / "trace")
    meta = json.loads((folder / "trace.json").read_text())
    assert meta["version"] == 1
    meta["config"] = json.loads(_V1_CONFIG.read_text())
    (folder / "trace.json").write_text(json.dumps(meta))
    # the fields added since then take the values that reproduce the code that wrote it
    old = with_fields(SegmentConfig(), ADDED_AFTER_V1)
    assert load_trace(folder).config == old
    assert old.grouping.substitute_stranded_parents is False and old.vote.revote_dropped is False


def _corrupt(tmp_path, edit) -> Path:
    folder = save_trace(tiny_segmentation().trace, tmp_path / "trace")
    meta = json.loads((folder / "trace.json").read_text())
    edit(meta["config"])
    (folder / "trace.json").write_text(json.dumps(meta))
    return folder


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda c: c["vote"].update(new_knob=3), "config.vote.new_knob"),
        (lambda c: c["vote"].pop("min_coverage"), "config.vote.min_coverage"),
        (lambda c: c.pop("grouping"), "config.grouping"),
        (lambda c: c["vote"].update(min_coverage="0.5"), "config.vote.min_coverage"),
        (lambda c: c["vote"].update(min_instance_points=30.5), "config.vote.min_instance_points"),
        (lambda c: c["vote"].update(label_support=1), "config.vote.label_support"),
        (lambda c: c["occupancy"].update(normalise="some"), "config.occupancy.normalise"),
        (lambda c: c.update(pointcloud=[1, 2]), "config.pointcloud"),
        (lambda c: c["pointcloud"].update(voxel_size=-1.0), "config.pointcloud"),
    ],
)
def test_an_unreadable_config_is_refused_naming_the_field(tmp_path, edit, field):
    folder = _corrupt(tmp_path, edit)
    with pytest.raises(SceneFileError) as e:
        load_trace(folder)
    assert e.value.path == folder / "trace.json"
    assert field in e.value.problem


def test_a_trace_without_config_is_refused(tmp_path):
    folder = save_trace(tiny_segmentation().trace, tmp_path / "trace")
    meta = json.loads((folder / "trace.json").read_text())
    del meta["config"]
    (folder / "trace.json").write_text(json.dumps(meta))
    with pytest.raises(SceneFileError, match="config"):
        load_trace(folder)


def test_trace_refuses_an_untyped_config():
    with pytest.raises(Exception, match="SegmentConfig"):
        replace(tiny_segmentation().trace, config=asdict(SegmentConfig()))


# ------------------------------------------------------------------ the paper preset and our additions


def _flat(cfg) -> dict:
    out = {}
    for k, v in asdict(cfg).items():
        if isinstance(v, dict):
            out.update({f"{k}.{kk}": vv for kk, vv in v.items()})
        else:
            out[k] = v
    return out


def test_ours_is_the_default_and_every_addition_is_on_in_it():
    assert PRESETS["default"] == SegmentConfig()
    ours = _flat(SegmentConfig())
    for a in ADDITIONS:
        for path, on, off in a.fields:
            assert ours[path] == on, (a.key, path)
            assert on != off, (a.key, path)


def test_the_paper_preset_differs_from_ours_exactly_in_the_additions():
    ours, paper = _flat(SegmentConfig()), _flat(PRESETS["paper"])
    differ = {k for k in ours if ours[k] != paper[k]}
    switched = [path for a in ADDITIONS for path, _, _ in a.fields]
    assert len(switched) == len(set(switched))  # no field belongs to two additions
    assert differ == set(switched)
    for a in ADDITIONS:
        for path, _, off in a.fields:
            assert paper[path] == off
    # the paper's text, spot checks (Sec. III-A eq. 1, III-B.1, III-B.2, III-B.4)
    p = PRESETS["paper"]
    assert not p.supervoxels.support_removal and not p.supervoxels.absolute_normal_dot
    assert p.trees.tau_contain == 1.0 and p.trees.min_area_px == 1
    assert not p.grouping.one_mask_per_view and not p.exclude_background_masks
    assert p.vote.min_instance_points == 0 and p.vote.min_coverage == 0.0 and p.occupancy.normalise == "all"
    # the paper's own values are shared (Sec. IV)
    assert (p.grouping.tau_spat, p.grouping.tau_sem, p.pointcloud.voxel_size, p.pointcloud.min_points) == (
        0.5, 0.65, 0.005, 3)


@pytest.mark.parametrize("key", [a.key for a in ADDITIONS])
def test_leave_one_out_changes_only_that_addition(key):
    add = {a.key: a for a in ADDITIONS}
    fields = {path for path, _, _ in add[key].fields}
    needed = {path for n in add[key].needs for path, _, _ in add[n].fields}
    ours, paper = _flat(SegmentConfig()), _flat(PRESETS["paper"])
    wo, wp = _flat(ours_without(key)), _flat(paper_with(key))
    assert {k for k in ours if ours[k] != wo[k]} == fields
    # in the paper preset, an addition that reads the support flags comes with the marking
    assert {k for k in paper if paper[k] != wp[k]} == fields | needed


def test_an_unknown_addition_or_field_is_refused():
    with pytest.raises(KeyError, match="no addition"):
        ours_without("nonsense")
    with pytest.raises(KeyError, match="no field"):
        with_fields(SegmentConfig(), {"vote.nonsense": 1})


def test_only_the_fields_added_after_v1_may_be_missing(tmp_path):
    data = json.loads(_V1_CONFIG.read_text())
    assert config_from_json(data, "trace.json").vote.revote_dropped is False
    data["vote"].pop("min_group_size")
    with pytest.raises(SceneFileError, match="config.vote.min_group_size"):
        config_from_json(data, "trace.json")
