"""Run folders: one detection rule, save / load, and the recorded scene folder."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from clutt3r_core import pipeline, runs
from clutt3r_core.errors import SceneFileError
from clutt3r_core.runs import (
    RUN_FILES,
    RunInfo,
    is_run_folder,
    load_run,
    read_run_info,
    run_scene_folder,
    save_run,
)

from ._tiny_run import tiny_segmentation


def test_pipeline_keeps_save_and_load_importable():
    assert pipeline.save_run is runs.save_run and pipeline.load_run is runs.load_run


def test_save_load_and_detection(tmp_path):
    seg = tiny_segmentation()
    run = save_run(seg, tmp_path / "run")
    assert is_run_folder(run)
    back = load_run(run)
    np.testing.assert_array_equal(back.instance, seg.instance)
    assert back.scene_name == seg.scene_name and back.trace.config == seg.trace.config
    info = read_run_info(run)
    assert info == RunInfo(scene_name=seg.scene_name, scene=None, created_by=info.created_by)
    assert info.created_by  # the version that wrote it
    assert run_scene_folder(run) is None
    assert not is_run_folder(tmp_path)  # an empty folder
    assert not is_run_folder(run / "instances.npz")  # a file


@pytest.mark.parametrize("name", RUN_FILES)
def test_a_folder_missing_any_run_file_is_not_a_run(tmp_path, name):
    run = save_run(tiny_segmentation(), tmp_path / "run")
    (run / name).unlink()
    assert not is_run_folder(run)
    with pytest.raises(SceneFileError) as e:
        load_run(run)
    assert e.value.path == run / name


def test_scene_recorded_relative_and_followed_when_moved_together(tmp_path):
    scene = tmp_path / "work" / "scene"
    scene.mkdir(parents=True)
    run = save_run(tiny_segmentation(), tmp_path / "work" / "runs" / "r1", scene_root=scene)
    recorded = json.loads((run / "run.json").read_text())["scene"]
    assert recorded == "../../scene"
    assert read_run_info(run).scene.as_posix() == "../../scene"
    assert run_scene_folder(run) == scene.resolve()
    # move both together: still found
    shutil.move(tmp_path / "work", tmp_path / "moved")
    assert run_scene_folder(tmp_path / "moved" / "runs" / "r1") == (tmp_path / "moved" / "scene").resolve()


def test_moved_scene_gives_a_clear_error(tmp_path):
    scene = tmp_path / "scene"
    scene.mkdir()
    run = save_run(tiny_segmentation(), tmp_path / "run", scene_root=scene)
    shutil.move(scene, tmp_path / "elsewhere")
    with pytest.raises(SceneFileError) as e:
        run_scene_folder(run)
    assert e.value.path == run / "run.json"
    assert "does not exist (moved?); pass --scene" in e.value.problem


def test_absolute_scene_path_is_used_as_recorded(tmp_path):
    scene = tmp_path / "scene"
    scene.mkdir()
    run = save_run(tiny_segmentation(), tmp_path / "run", scene_root=scene)
    info = json.loads((run / "run.json").read_text())
    info["scene"] = str(scene.resolve())  # as written when no relative path exists
    (run / "run.json").write_text(json.dumps(info))
    assert run_scene_folder(run) == scene.resolve()


def test_a_run_without_run_json_still_loads(tmp_path):
    run = save_run(tiny_segmentation(), tmp_path / "run")
    (run / "run.json").unlink()
    assert read_run_info(run) == RunInfo()
    assert load_run(run).scene_name == ""
    assert run_scene_folder(run) is None


def test_a_bad_run_json_is_refused(tmp_path):
    run = save_run(tiny_segmentation(), tmp_path / "run")
    (run / "run.json").write_text('{"scene": 3}')
    with pytest.raises(SceneFileError) as e:
        read_run_info(run)
    assert e.value.path == run / "run.json"


def test_segment_command_records_the_scene(tmp_path):
    from clutt3r_core.commands.segment import segment_command
    from clutt3r_core.io import write_sample_layout

    from ._tiny_run import tiny_scene

    scene_dir = tmp_path / "scene"
    write_sample_layout(tiny_scene(), scene_dir)
    segment_command(scene_dir, tmp_path / "run")
    assert is_run_folder(tmp_path / "run")
    assert run_scene_folder(tmp_path / "run") == scene_dir.resolve()
