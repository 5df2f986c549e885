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
    r1 = _fake_update(s0, 8, k=0, shift=0.15, removed=None, n_iter=5)  # a big move: visible on the canvas
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
