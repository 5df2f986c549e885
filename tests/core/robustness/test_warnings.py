"""Run warnings (``clutt3r_core.diagnostics``): typed, one line each, kept in run.json, never
silently lost; the view checks fire on the degradation they name and not on clean scenes."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.diagnostics import (
    DEPTH_INVALID_FRACTION,
    WARNING_CODES,
    RunWarning,
    check_usable_depth,
    invalid_depth_fraction,
    view_warnings,
)
from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io import load_scene
from clutt3r_core.pipeline import segment
from clutt3r_core.pointcloud import PointCloudConfig, fuse_views
from clutt3r_core.runs import load_run, read_run_info, save_run
from clutt3r_core.scene import Scene
from tests.core.robustness._scenes import make_scene

CFG = PointCloudConfig()

warning_st = st.builds(
    RunWarning,
    code=st.sampled_from(sorted(WARNING_CODES)),
    message=st.text(st.characters(blacklist_characters="\n\r", blacklist_categories=("Cs",)), max_size=80),
    frame=st.none() | st.integers(0, 10**6),
    view=st.text(st.characters(blacklist_categories=("Cs",)), max_size=20),
)


@given(st.lists(warning_st, max_size=5))
@settings(max_examples=50, deadline=None)
def test_warnings_round_trip_through_json(ws):
    text = json.dumps([w.to_json() for w in ws])
    assert tuple(RunWarning.from_json(d) for d in json.loads(text)) == tuple(ws)


def test_warning_validation():
    with pytest.raises(SceneError, match="unknown run warning code"):
        RunWarning("nope", "x")
    with pytest.raises(SceneError, match="one line"):
        RunWarning("view-dropped", "two\nlines")
    for bad in ([], {"code": "view-dropped"}, {"code": "view-dropped", "message": "m", "frame": "3"},
                {"code": "view-dropped", "message": "m", "frame": True}):
        with pytest.raises(SceneError):
            RunWarning.from_json(bad)


def test_clean_scene_has_no_warning():
    scene = make_scene(3)
    views = list(scene.initial_views)
    assert view_warnings(views, fuse_views(views, CFG), CFG) == ()


def test_mostly_invalid_depth_is_warned_above_the_threshold_only():
    scene = make_scene(3)
    views = list(scene.initial_views)
    d = views[2].depth.copy()
    # invalidate whole rows until just past / just below the threshold
    for frac, expect in ((DEPTH_INVALID_FRACTION + 0.1, True), (DEPTH_INVALID_FRACTION - 0.1, False)):
        dd = d.copy()
        rows = int(round(frac * dd.shape[0]))
        dd[:rows] = 0.0  # a 0 in a file is a hole: the view makes it NaN
        dd[rows:][~np.isfinite(dd[rows:])] = 0.6  # off-table sky: make it valid so the fraction is exact
        vs = views[:2] + [replace(views[2], depth=dd)]
        assert invalid_depth_fraction(vs[2], CFG) == pytest.approx(rows / dd.shape[0])
        codes = [(w.code, w.frame) for w in view_warnings(vs, fuse_views(vs, CFG), CFG)]
        assert (("depth-invalid", 2) in codes) == expect, codes


def test_depth_beyond_range_counts_as_invalid():
    v = make_scene(1).views[0]
    far = replace(v, depth=np.full_like(v.depth, CFG.max_depth + 1.0))
    assert invalid_depth_fraction(far, CFG) == 1.0
    near = replace(v, depth=np.full_like(v.depth, CFG.min_depth / 2))
    assert invalid_depth_fraction(near, CFG) == 1.0


def test_no_usable_depth_error_names_every_view():
    scene = make_scene(2)
    vs = [replace(v, depth=np.full_like(v.depth, np.nan)) for v in scene.views]
    with pytest.raises(SceneError) as ei:
        check_usable_depth(vs, fuse_views(vs, CFG), CFG)
    msg = str(ei.value)
    assert "no usable depth in any view" in msg and "every depth pixel is a hole" in msg
    assert "frame 0 (image_000000.png)" in msg and "frame 1 (image_000001.png)" in msg
    with pytest.raises(SceneError, match="no usable depth"):
        segment(Scene(views=tuple(vs), initial=(0, 1)))


def test_too_few_points_for_a_voxel_is_said_so():
    v = make_scene(1).views[0]
    d = np.full_like(v.depth, np.nan)
    d[0, 0] = 0.5  # one valid pixel: fewer than min_points in its voxel
    vs = [replace(v, depth=d)]
    with pytest.raises(SceneError, match="too few depth points to fill one 5 mm voxel"):
        check_usable_depth(vs, fuse_views(vs, CFG), CFG)


def test_warnings_are_kept_in_the_run(tmp_path):
    scene = make_scene(3)
    vs = list(scene.views)
    vs[1] = replace(vs[1], masks=type(vs[1].masks).empty(vs[1].camera.height, vs[1].camera.width))
    seg = segment(Scene(views=tuple(vs), initial=(0, 1, 2), name="w"))
    assert [(w.code, w.frame) for w in seg.warnings] == [("view-no-masks", 1)]
    save_run(seg, tmp_path / "run")
    assert read_run_info(tmp_path / "run").warnings == seg.warnings
    assert load_run(tmp_path / "run").warnings == seg.warnings


def test_run_json_with_bad_warnings_is_refused(tmp_path):
    (tmp_path / "run.json").write_text(json.dumps({"scene_name": "x", "warnings": {"a": 1}}))
    with pytest.raises(SceneFileError, match="'warnings' must be a list"):
        read_run_info(tmp_path)
    (tmp_path / "run.json").write_text(json.dumps({"warnings": [{"code": "bogus", "message": "m"}]}))
    with pytest.raises(SceneFileError, match="bad entry in 'warnings'.*unknown run warning code"):
        read_run_info(tmp_path)
    (tmp_path / "run.json").write_text(json.dumps({"scene_name": "old run"}))  # before warnings existed
    assert read_run_info(tmp_path).warnings == ()


def test_roles_named_in_a_file_give_no_demotion_warning(scene_dir):
    # clutt3r_scene.json names the roles: a post frame without depth is expected, not a guess
    meta = json.loads((scene_dir / "clutt3r_scene.json").read_text())
    meta["initial_frames"], meta["post_frames"] = [0, 1], [2]
    (scene_dir / "clutt3r_scene.json").write_text(json.dumps(meta))
    (scene_dir / "depth" / "depth_000002.png").unlink()
    sc = load_scene(scene_dir)
    assert sc.warnings == () and [v.frame for v in sc.post_views] == [2]
    (scene_dir / "clutt3r_scene.json").unlink()
    sc = load_scene(scene_dir)
    assert [(w.code, w.frame) for w in sc.warnings] == [("frame-demoted", 2)]
