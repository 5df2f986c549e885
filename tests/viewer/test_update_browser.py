"""The scene-update replay in headless chromium (issue 10): choose the pose-iteration source in
the Replay tab, step it to the end and back, and see the displaced points move."""

from __future__ import annotations

import shutil
import time

import numpy as np
import pytest

from clutt3r_core.update.state import apply_update, save_state, state_from_segmentation
from tests.viewer.conftest import free_port
from tests.viewer.test_browser import _canvas_shot, _open, _tab, _wait, browser  # noqa: F401  (fixture)
from tests.viewer.test_update_sources import _fake_update

pytestmark = [pytest.mark.browser, pytest.mark.slow]

SOURCE = "scene updates: pose iterations"


@pytest.fixture(scope="module")
def update_app(tiny_run_dir, tiny_seg, tmp_path_factory):
    import clutt3r_viewer
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader and the source)

    run = tmp_path_factory.mktemp("update_run") / "run"
    shutil.copytree(tiny_run_dir, run)
    s0 = state_from_segmentation(tiny_seg, run=run)
    r1 = _fake_update(s0, 8, k=0, shift=0.15, removed=2, n_iter=5)  # a big move: visible on the canvas
    save_state(apply_update(s0, r1), run / "updates" / "01_frame_000008", r1)
    a = clutt3r_viewer.start(run, port=free_port())
    yield a
    a.stop()


def test_replay_steps_the_pose_iterations(browser, update_app, artifacts):  # noqa: F811
    page, sess = _open(browser, update_app)
    src = next(s for s in update_app.sources if s.name == SOURCE)
    _tab(page, "Replay")
    page.locator("input[value='grouping']").locator("visible=true").first.click()  # the Events dropdown
    page.get_by_role("option", name=SOURCE).click()
    _wait(lambda: sess.state.replay_source == SOURCE, what="pose-iteration source selected")
    time.sleep(1.5)
    start = _canvas_shot(page)
    slider = page.get_by_role("slider").locator("visible=true").first
    # the new source's range reaches the page after the server switched (test_scene_step_browser)
    _wait(lambda: slider.get_attribute("aria-valuemax") == str(max(src.num_events, 1)),
          what="the slider's range of the pose-iteration source")
    slider.focus()
    page.keyboard.press("End")
    _wait(lambda: sess.state.event == src.num_events, what="replay at the last iteration")
    time.sleep(1.5)
    end = _canvas_shot(page)
    page.screenshot(path=str(artifacts / "viewer_update_replay_end.png"))
    assert page.get_by_text(f"iteration {src.num_events}/{src.num_events}").count() >= 1
    assert np.abs(end - start).sum(-1).astype(bool).mean() > 0.002, "the displaced points did not move"
    page.keyboard.press("Home")
    _wait(lambda: sess.state.event == 0, what="replay back at iteration 0")

    # the Updates tab: choosing the update draws its loss and IoU curves
    from clutt3r_viewer.panels.update_curves import UpdateCurvesPanel

    _tab(page, "Updates")
    slider = page.get_by_role("slider").locator("visible=true").first
    slider.focus()
    page.keyboard.press("End")  # update 0 (the slider runs from -1 = the initial segmentation)
    _wait(lambda: sess.state.update == 0, what="update 0 selected")
    panel = sess.panel(UpdateCurvesPanel)
    _wait(lambda: panel.loss is not None and panel.iou is not None, what="curves drawn")
    time.sleep(1.0)
    page.screenshot(path=str(artifacts / "viewer_update_curves.png"))
    page.close()


def test_updates_tab_moves_the_points_to_the_updated_poses(browser, update_app, artifacts):  # noqa: F811
    """Choosing update 0 in the Updates tab moves the displaced instance's points (15 cm) on the
    canvas and draws the removed one pale; unchecking "After the update" puts them back where
    they were before it."""
    from clutt3r_viewer.panels.scene import ScenePanel

    page, sess = _open(browser, update_app)
    d = update_app.data
    _tab(page, "Updates")
    initial = _canvas_shot(page)
    slider = page.get_by_role("slider").locator("visible=true").first
    slider.focus()
    page.keyboard.press("End")
    _wait(lambda: sess.state.update == 0 and sess.state.color_mode == "update", what="update 0 shown")
    cloud = sess.panel(ScenePanel).cloud
    moved = d.seg.instance[sess.lod_idx] == 0
    run_pts = (d.seg.points[sess.lod_idx] - d.centre).astype(np.float32)
    _wait(lambda: np.allclose(np.asarray(cloud.points)[moved, 0] - run_pts[moved, 0], 0.15, atol=2e-3),
          what="the displaced points at their updated pose (server side)")
    assert np.allclose(np.asarray(cloud.points)[~moved], run_pts[~moved], atol=2e-3)  # the rest stay
    time.sleep(1.5)
    after = _canvas_shot(page)
    page.screenshot(path=str(artifacts / "viewer_update_after.png"))
    colours_after = np.asarray(cloud.colors).copy()

    page.get_by_text("After the update").click()
    _wait(lambda: not sess.state.update_after, what="before the update")
    _wait(lambda: np.allclose(np.asarray(cloud.points), run_pts, atol=2e-3), what="points back before the update")
    time.sleep(1.5)
    before = _canvas_shot(page)
    page.screenshot(path=str(artifacts / "viewer_update_before.png"))
    # only the removed instance's colour differs (pale after the update, its own colour before)
    gone = d.seg.instance[sess.lod_idx] == 2
    was = np.asarray(cloud.colors)[gone].astype(int)
    assert gone.any() and np.all(colours_after[gone] >= was) and np.all(colours_after[gone].sum(-1) > was.sum(-1))
    assert np.array_equal(np.asarray(cloud.colors)[~gone], colours_after[~gone])
    changed = np.abs(after.astype(int) - before.astype(int)).sum(-1) > 30
    assert changed.mean() > 0.002, f"the displaced points did not move on the canvas ({changed.mean():.4f})"
    same = np.abs(initial.astype(int) - before.astype(int)).sum(-1) > 30
    assert same.mean() < changed.mean() / 2, "before the update should look like the initial scene"
    page.close()
