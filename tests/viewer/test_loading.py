"""clutt3r_viewer.loading: run folders, scene links, hooks, text-embedder detection."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.errors import SceneFileError
from clutt3r_viewer.data import UpdateFrame
from clutt3r_viewer.loading import (
    _UPDATE_LOADERS,
    find_scene,
    is_run_dir,
    load_viewer_data,
    register_update_loader,
    text_embedder_for,
)


def test_run_folder_loads_without_recomputing(tiny_run_dir, tiny_data):
    assert is_run_dir(tiny_run_dir)
    assert find_scene(tiny_run_dir) is not None
    d = load_viewer_data(tiny_run_dir)
    assert len(d.views) == len(tiny_data.views)
    assert np.array_equal(d.seg.instance, tiny_data.seg.instance)
    assert np.array_equal(d.edges, tiny_data.edges)
    assert d.grasps is None and d.updates == ()


def test_bad_scene_link_names_the_file(tiny_run_dir, tmp_path):
    import shutil

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    (run / "viewer.json").write_text(json.dumps({"scene": str(tmp_path / "nowhere")}))
    with pytest.raises(SceneFileError, match="viewer.json"):
        find_scene(run)
    (run / "viewer.json").unlink()
    assert find_scene(run) is None
    assert load_viewer_data(run).views == ()  # still viewable, without images


def test_update_hook_feeds_the_updates_tab(tiny_run_dir):
    @register_update_loader
    def fake(run_dir, scene):
        return (UpdateFrame(frame=99, text="object 2 removed"),)

    try:
        d = load_viewer_data(tiny_run_dir)
        assert [u.frame for u in d.updates] == [99]
    finally:
        _UPDATE_LOADERS.remove(fake)


def test_text_embedder_only_when_the_backend_embeds_text(tiny_data):
    from clutt3r_core.embeddings import AppearanceEmbedder

    assert text_embedder_for(tiny_data).name == "fake-text"  # the run's own embedder (registered in conftest)
    assert text_embedder_for(tiny_data, AppearanceEmbedder()) is None  # NotImplementedError -> no Query tab


def test_a_scene_folder_is_segmented_in_the_background(tiny_run_dir, tiny_data):
    import time

    import clutt3r_viewer
    from tests.viewer.conftest import free_port

    app = clutt3r_viewer.start(tiny_run_dir.parent / "scene", port=free_port())
    try:
        t0 = time.time()
        while app.data is None and time.time() - t0 < 60:
            time.sleep(0.2)
        assert app.data is not None, f"not ready: {app._status}"
        assert app.data.seg.num_instances > 0 and len(app.data.views) == len(tiny_data.views)
    finally:
        app.stop()


def _run_with_recorded_scene(tiny_seg, tiny_scene, root):
    from clutt3r_core.io import write_sample_layout
    from clutt3r_core.runs import save_run

    scene_dir = write_sample_layout(tiny_scene, root / "scenes" / "s")
    return save_run(tiny_seg, root / "runs" / "r", scene_root=scene_dir), scene_dir


def test_a_run_finds_the_scene_it_recorded_and_scene_overrides_it(tiny_seg, tiny_scene, tiny_run_dir, tmp_path):
    run, scene_dir = _run_with_recorded_scene(tiny_seg, tiny_scene, tmp_path)
    assert not (run / "viewer.json").exists()
    assert find_scene(run).resolve() == scene_dir.resolve()
    d = load_viewer_data(run)
    assert len(d.views) == len(tiny_scene.initial) and d.scene_root.resolve() == scene_dir.resolve()
    other = tiny_run_dir.parent / "scene"  # --scene wins over the record
    assert load_viewer_data(run, other).scene_root.resolve() == other.resolve()
    # run and scene moved together: the relative record still holds
    import shutil

    shutil.move(str(tmp_path / "runs"), str(tmp_path / "moved" / "runs"))
    shutil.move(str(tmp_path / "scenes"), str(tmp_path / "moved" / "scenes"))
    assert find_scene(tmp_path / "moved" / "runs" / "r").resolve() == (tmp_path / "moved" / "scenes" / "s").resolve()


def test_a_moved_scene_is_a_clear_error_and_no_images_opens_the_run(tiny_seg, tiny_scene, tmp_path, capsys):
    import shutil

    run, scene_dir = _run_with_recorded_scene(tiny_seg, tiny_scene, tmp_path)
    shutil.move(str(scene_dir), str(tmp_path / "elsewhere"))
    with pytest.raises(SceneFileError, match="run.json") as e:
        find_scene(run)
    msg = str(e.value)
    assert "scenes/s" in msg and "--scene" in msg and "--no-images" in msg
    assert load_viewer_data(run, images=False).views == ()
    assert len(load_viewer_data(run, tmp_path / "elsewhere").views) == len(tiny_scene.initial)
    from tests.viewer.conftest import free_port

    from clutt3r_core.cli import main

    with pytest.raises(SystemExit) as ex:  # the CLI: one line on stderr, exit 2, no server left running
        main(["view", str(run), "--port", str(free_port())])
    assert ex.value.code == 2
    err = capsys.readouterr().err
    assert err.startswith("clutt3r: error: ") and "run.json" in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1
    import clutt3r_viewer

    app = clutt3r_viewer.start(run, port=free_port(), images=False)
    try:
        assert app.data.views == () and "--no-images" in app.no_images_text
    finally:
        app.stop()
