"""The Edit tab in headless chromium: an edit is on disk at once, Undo reverts it, every tab recolours."""

from __future__ import annotations

import json
import shutil
import time

import numpy as np
import pytest

from clutt3r_core.annotations import LOG_NAME
from clutt3r_viewer.panels import TreePanel
from tests.viewer.conftest import free_port
from tests.viewer.test_browser import _canvas_shot, _open, _tab, _wait, browser  # noqa: F401 (fixture)

pytestmark = [pytest.mark.browser, pytest.mark.slow]


@pytest.fixture
def edit_app(tiny_run_dir, tmp_path):
    import clutt3r_viewer

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)  # the shared run folder stays without corrections
    a = clutt3r_viewer.start(run, port=free_port())
    yield a, run
    a.stop()


def _colour_share(canvas: np.ndarray, k: int) -> float:
    """Fraction of canvas pixels drawn in instance k's palette colour (software WebGL adds a little noise)."""
    from clutt3r_viewer.data import PALETTE

    return float((np.abs(canvas - PALETTE[k].astype(np.int16)).max(-1) < 25).mean())


def _log(run) -> list[dict]:
    p = run / LOG_NAME
    return [json.loads(x) for x in p.read_text().splitlines()[1:]] if p.exists() else []


def test_edit_tab_merge_is_logged_at_once_and_undo_reverts_it(browser, edit_app, artifacts):  # noqa: F811
    app, run = edit_app
    seg = app.data.seg
    assert seg.num_instances >= 2
    page, sess = _open(browser, app)
    page2, sess2 = _open(browser, app)
    _tab(page, "Edit")
    assert sess.state.edit_instance == 0
    time.sleep(1.0)
    before = _colour_share(_canvas_shot(page), 0)
    assert before > 0.003, "instance 0 is not visible on the canvas"
    updates2 = sess2.colour_updates
    page.get_by_role("button", name="Merge instance into target").click()
    _wait(lambda: len(_log(run)) == 1, what="the merge in ops.jsonl")
    op = _log(run)[0]
    assert (op["op"], op["other"], op["into"]) == ("merge", 0, 1)
    _wait(lambda: sess2.colour_updates > updates2, what="the other tab recoloured")
    lab = app.annotations.current
    assert not (lab.instance == 0).any() and np.array_equal(lab.instance == 1, (seg.instance == 0) | (seg.instance == 1))
    _wait(lambda: page.get_by_text("1 edit", exact=False).count() >= 1, what="status line")
    assert app.annotations.num_ops == 1  # durable in the log; the snapshot is a periodic checkpoint
    time.sleep(1.5)
    page.screenshot(path=str(artifacts / "viewer_edit_merged.png"))
    assert _colour_share(_canvas_shot(page), 0) < 0.1 * before, "the merge did not recolour instance 0"

    page.get_by_role("button", name="Undo").click()
    _wait(lambda: len(_log(run)) == 2, what="the undo in ops.jsonl")
    assert _log(run)[1]["op"] == "undo" and _log(run)[1]["target"] == 0
    # the log line is written (fsync) before the in-memory state moves: wait for the state too
    _wait(lambda: np.array_equal(app.annotations.current.instance, seg.instance), what="undo applied in memory")
    assert app.annotations.can_redo and not app.annotations.can_undo
    _wait(lambda: page.get_by_text("0 edits", exact=False).count() >= 1, what="status after undo")
    time.sleep(1.5)
    page.screenshot(path=str(artifacts / "viewer_edit_undone.png"))
    assert _colour_share(_canvas_shot(page), 0) > 0.8 * before, "undo did not bring instance 0 back"

    # a tree node's super-voxels -> a new instance (the redo stack is cleared by the new edit)
    d = app.data
    leaf = int(next(i for i in d.view_nodes(0) if d.trace.nodes.is_leaf[i] and d.node_instance[i] >= 0))
    _tab(page, "Tree")
    page.get_by_role("button", name=sess.panel(TreePanel).buttons[leaf].label).first.click()
    _wait(lambda: sess.state.node == leaf and sess.state.edit_instance == int(d.node_instance[leaf]),
          what="node selection picks its instance")
    _tab(page, "Edit")
    page.get_by_role("button", name="Move node's super-voxels to a new instance").click()
    _wait(lambda: len(_log(run)) == 3, what="the split in ops.jsonl")
    assert _log(run)[2]["op"] == "split"
    k = seg.num_instances
    _wait(lambda: app.annotations.current.num_instances == k + 1, what="split applied in memory")
    assert (app.annotations.current.instance == k).any()
    _wait(lambda: sess.state.edit_instance == k, what="the new instance selected")
    assert not app.annotations.can_redo
    page.close()
    page2.close()
