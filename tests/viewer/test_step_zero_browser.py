"""A merge in the Edit tab reaches the Grasps tab at step 0, in headless chromium (session 9).

The user picks two instances in the Edit tab, presses "Merge instance into target", then plans grasps
in the Grasps tab: the merged id is gone from the target list and the plan for the id it joined is
made on both instances' points (``scene_step.step_zero_of``). The page's buttons and tabs are real
clicks; the dropdown choices are set on the server (what a dropdown pick sends)."""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_viewer.edit import option_id
from clutt3r_viewer.panels.edit import EditPanel
from clutt3r_viewer.panels.grasps import GraspsPanel
from tests.viewer.test_browser import _open, _tab, _wait, browser  # noqa: F401 (fixture)
from tests.viewer.test_edit_browser import edit_app  # noqa: F401 (fixture: the viewer on a copy of the run)

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def test_merge_in_the_edit_tab_then_plan_grasps_on_the_merged_instance(browser, edit_app, artifacts):  # noqa: F811
    from clutt3r_core.segmentation.refine import run_labels_before_contact

    app, _ = edit_app
    seg = app.data.seg
    counts = np.bincount(seg.instance[seg.instance >= 0], minlength=seg.num_instances)
    a, b = (int(k) for k in np.argsort(-counts)[-2:])  # two small ones (the hand can hold them)
    pre = run_labels_before_contact(seg)
    page, sess = _open(browser, app)

    _tab(page, "Edit")
    edit = sess.panel(EditPanel)
    with sess.lock:
        edit._pick(sess, b)  # the Instance dropdown: b
        edit.into.value = next(o for o in edit.into.options if option_id(o) == a)  # Merge into: a
    page.get_by_role("button", name="Merge instance into target").click()
    _wait(lambda: app.annotations.num_ops == 1, what="the merge applied")
    assert not (app.annotations.current.instance == b).any()

    _tab(page, "Grasps")
    grasps = sess.panel(GraspsPanel)
    _wait(lambda: b not in {option_id(o) for o in grasps.target.options}, what="the merged id left the target list")
    grasps.target.value = next(o for o in grasps.target.options if option_id(o) == a)
    page.get_by_role("button", name="Plan grasps").click()
    n = int(np.isin(pre, [a, b]).sum())
    _wait(lambda: "target points" in grasps.summary.content, timeout=60.0, what="the plan")
    assert f"I{a} ({n} target points)" in grasps.summary.content, grasps.summary.content
    _wait(lambda: page.get_by_text(f"({n} target points)").count() >= 1, what="the summary on the page")
    page.screenshot(path=str(artifacts / "viewer_step0_merged_grasps.png"))
