"""The viewer in headless chromium (playwright, Debian's /usr/bin/chromium, software WebGL).

The server runs in-process on a free port with the tiny generated scene; each test
drives the page like a user and asserts on the server-side session state the GUI
event changed, and on screenshots (saved under test-artifacts/).
"""

from __future__ import annotations

import io
import time

import numpy as np
import pytest

from clutt3r_viewer.headless import CHROMIUM, CHROMIUM_ARGS
from clutt3r_viewer.panels import TreePanel
from tests.viewer.conftest import free_port

pytestmark = [pytest.mark.browser, pytest.mark.slow]



@pytest.fixture(scope="module")
def browser():
    if not CHROMIUM.exists():
        pytest.skip(f"chromium not found at {CHROMIUM} (apt-get install chromium); browser tests skipped")
    pw_mod = pytest.importorskip("playwright.sync_api", reason="the playwright package is not installed")
    with pw_mod.sync_playwright() as pw:
        b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
def app(tiny_run_dir):
    import clutt3r_viewer

    a = clutt3r_viewer.start(tiny_run_dir, port=free_port())
    yield a
    a.stop()


def _image(png: bytes) -> np.ndarray:
    from PIL import Image

    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.int16)


def _wait(pred, timeout=15.0, what="condition"):
    t0 = time.time()
    while time.time() - t0 < timeout:
        if pred():
            return
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def _open(browser, app):
    known = set(app.sessions)
    page = browser.new_page(viewport={"width": 1280, "height": 800})
    page.goto(app.url)
    page.wait_for_selector("canvas", timeout=30_000)
    new = lambda: [s for k, s in list(app.sessions.items()) if k not in known and s.built]  # noqa: E731
    _wait(lambda: len(new()) == 1, what="session build")
    sess = new()[0]
    time.sleep(2.5)  # software WebGL: let a few frames render
    return page, sess


def _canvas_shot(page) -> np.ndarray:
    # a clipped page screenshot: element screenshots wait ~15 s for "stability" under software WebGL
    box = page.locator("canvas").first.bounding_box()
    clip = {"x": box["x"], "y": box["y"], "width": min(box["width"], 860), "height": box["height"]}
    return _image(page.screenshot(clip=clip))


def _tab(page, name):
    page.get_by_role("tab", name=name).click()
    time.sleep(0.3)


def test_page_renders_the_scene_and_the_tree_and_replay_drive_the_server(browser, app, artifacts):
    page, sess = _open(browser, app)
    d = app.data
    page.screenshot(path=str(artifacts / "viewer_initial.png"))
    canvas = _canvas_shot(page)
    # not blank: the cloud's instance colours are on the canvas, not just the background
    assert canvas.std() > 10
    colourful = (canvas.max(-1) - canvas.min(-1)) > 60
    assert colourful.mean() > 0.005, "no coloured points on the canvas: the cloud is missing or off-screen"

    # select another view in the View dropdown -> its tree is listed
    page.get_by_role("textbox", name="View").click() if page.get_by_role("textbox", name="View").count() else \
        page.locator("input[value^='0: frame']").first.click()
    target = f"1: frame {int(d.trace.frames[1])}"
    page.get_by_role("option", name=target).click()
    _wait(lambda: sess.state.view == 1, what="view selection")
    _tab(page, "Tree")
    vi_nodes = d.view_nodes(1)
    leaf = int(next(i for i in vi_nodes if d.trace.nodes.is_leaf[i] and not d.trace.nodes.background[i]))
    label = sess.panel(TreePanel).buttons[leaf]
    btn = page.get_by_role("button", name=label.label)
    assert btn.count() >= 1, "tree of the selected view is not shown"
    assert page.get_by_text(f"Tree of frame {int(d.trace.frames[1])}").count() == 1
    before = _canvas_shot(page)
    btn.first.click()
    _wait(lambda: sess.state.node == leaf, what="node selection")
    time.sleep(1.5)
    page.screenshot(path=str(artifacts / "viewer_node_selected.png"))
    after = _canvas_shot(page)
    assert np.abs(after - before).sum(-1).astype(bool).mean() > 0.01  # the cloud was recoloured
    page.get_by_role("button", name="Clear selection").click()
    _wait(lambda: sess.state.node == -1, what="clear selection")

    # the grouping slider changes the displayed groups
    _tab(page, "Replay")
    time.sleep(1.0)
    start = _canvas_shot(page)
    slider = page.get_by_role("slider").locator("visible=true").first
    slider.focus()
    page.keyboard.press("End")
    _wait(lambda: sess.state.event == d.num_events and sess.state.color_mode == "replay", what="replay at the end")
    time.sleep(1.5)
    at_end = _canvas_shot(page)
    page.screenshot(path=str(artifacts / "viewer_replay_end.png"))
    assert page.get_by_text(f"{d.num_events}/{d.num_events}").count() >= 1  # event text updated
    page.keyboard.press("Home")
    _wait(lambda: sess.state.event == 0, what="replay at event 0")
    time.sleep(1.5)
    at0 = _canvas_shot(page)
    page.screenshot(path=str(artifacts / "viewer_replay_start.png"))
    assert d.replay_num_groups(0) > d.replay_num_groups(d.num_events)
    assert np.abs(at_end - at0).sum(-1).astype(bool).mean() > 0.005, "replay did not change the colours"
    assert start.shape == at0.shape
    page.close()


def test_query_highlights_an_instance_and_tabs_are_independent(browser, app, artifacts):
    page1, s1 = _open(browser, app)
    page2, s2 = _open(browser, app)
    assert s1 is not s2
    _tab(page1, "Query")
    box = page1.get_by_role("textbox").locator("visible=true").last
    box.fill("red")
    box.press("Enter")
    _wait(lambda: s1.state.query == "red" and s1.state.query_best >= 0, what="query callback")
    expect = int(np.argmax(app.data.instance_text_scores(app.text_embedder.embed_text(["red"])[0])))
    assert s1.state.query_best == expect
    time.sleep(1.5)
    page1.screenshot(path=str(artifacts / "viewer_query_red.png"))
    canvas = _canvas_shot(page1)
    yellow = (canvas[..., 0] > 200) & (canvas[..., 1] > 170) & (canvas[..., 2] < 90)
    assert yellow.mean() > 0.0005, "the best instance is not highlighted on the canvas"
    assert page1.get_by_text(f"→ I{expect}").count() >= 1
    # the other tab did not change
    assert s2.state.query == "" and s2.state.query_best == -1 and s2.state.color_mode == "instance"
    page1.close()
    page2.close()
