"""The Explain tab in headless chromium: "Why not?" for two masks picked in the Tree tab and
typed, the jump to the divergence step in the Replay tab, and "Why here?" for a super-voxel
Alt+clicked on the canvas (a real canvas click: the page sends viser's click ray, the server
picks the front-most point along it). Screenshots go to test-artifacts/explain_*.png.
"""

from __future__ import annotations

import time

import numpy as np
import pytest

from clutt3r_core.explain import explain_pair
from clutt3r_viewer.panels import ExplainPanel, ReplayPanel, TreePanel
from clutt3r_viewer.selection import ScreenCamera, pick_along_ray
from tests.viewer.test_browser import _canvas_shot, _open, _tab, _wait, app, browser  # noqa: F401

pytestmark = [pytest.mark.browser, pytest.mark.slow]


def _apart_pair(d):
    """Two leaves of views 0 and 1 that ended apart with the latest divergence step (a real 'why not')."""
    tr = d.trace
    n = tr.nodes
    best = None
    for a in d.view_nodes(0):
        for b in d.view_nodes(1):
            if n.is_leaf[a] and n.is_leaf[b] and not (n.background[a] or n.background[b]):
                e = explain_pair(tr, int(a), int(b))
                if not e.together and (best is None or e.diverge_step > best.diverge_step):
                    best = e
    assert best is not None
    return best


def test_why_not_reads_the_explanation_and_jumps_the_replay(browser, app, artifacts):  # noqa: F811
    page, sess = _open(browser, app)
    d = app.data
    expect = _apart_pair(d)
    # mask A from the Tree tab's selection
    _tab(page, "Tree")
    label = sess.panel(TreePanel).buttons[expect.a].label
    page.get_by_role("button", name=label).first.click()
    _wait(lambda: sess.state.node == expect.a, what="tree selection")
    _tab(page, "Explain")
    page.get_by_role("button", name="A = Tree selection").click()
    ep = sess.panel(ExplainPanel)
    ka = f"{expect.key_a[0]}:{expect.key_a[1]}"
    _wait(lambda: ep.mask_a.value == ka, what="mask A from the tree")
    # mask B typed
    box = page.get_by_role("textbox").locator("visible=true").nth(1)  # Mask A, Mask B, ... (labels are not linked)
    box.fill(f"{expect.key_b[0]}:{expect.key_b[1]}")
    box.press("Enter")
    _wait(lambda: ep.mask_b.value == f"{expect.key_b[0]}:{expect.key_b[1]}", what="mask B typed")
    page.get_by_role("button", name="Why not?").click()
    _wait(lambda: ep.result is not None, what="explanation")
    assert ep.result.rule == expect.rule and ep.result.diverge_step == expect.diverge_step
    # the explanation is on the page, in words and numbers
    page.get_by_text("first kept apart by").first.wait_for(timeout=10_000)
    assert page.get_by_text(f"tau_spat {expect.tau_spat:.2f}").count() >= 1
    assert page.get_by_text(expect.rule).count() >= 1
    page.get_by_text("fates diverged at replay step").first.scroll_into_view_if_needed()
    time.sleep(1.0)
    page.screenshot(path=str(artifacts / "explain_why_not.png"))

    # jump to the divergence: the Replay tab shows that step with the pair followed
    page.get_by_role("button", name=f"Replay: go to step {expect.diverge_step}").click()
    _wait(lambda: sess.state.event == expect.diverge_step and sess.state.color_mode == "replay",
          what="replay at the divergence")
    rp = sess.panel(ReplayPanel)
    assert rp.focus == (expect.a, expect.b)
    _tab(page, "Replay")
    assert page.get_by_text("explained pair").count() >= 1
    assert page.get_by_text(f"{expect.diverge_step}/{d.num_events}").count() >= 1
    if expect.diverge_step > 0:  # a merge or substitution step: its two groups are drawn over the cloud
        assert rp.cloud_a is not None and rp.cloud_a.visible
        time.sleep(1.5)
        canvas = _canvas_shot(page)
        orange = (canvas[..., 0] > 200) & (np.abs(canvas[..., 1] - 120) < 50) & (canvas[..., 2] < 80)
        blue = (canvas[..., 2] > 200) & (np.abs(canvas[..., 1] - 140) < 60) & (canvas[..., 0] < 80)
        assert orange.mean() + blue.mean() > 0.0005, "the step's groups are not highlighted on the canvas"
    page.get_by_text("explained pair").first.scroll_into_view_if_needed()
    time.sleep(0.5)
    page.screenshot(path=str(artifacts / "explain_replay_divergence.png"))
    page.close()


def test_why_here_from_a_canvas_click(browser, app, artifacts):  # noqa: F811
    page, sess = _open(browser, app)
    d = app.data
    _tab(page, "Explain")
    page.locator("input[value='nothing']").first.click()  # the pick-mode dropdown
    page.get_by_role("option", name="super-voxel").click()
    ep = sess.panel(ExplainPanel)
    _wait(lambda: ep.pick.value == "super-voxel", what="pick mode")
    # aim at a labelled point near the middle of the labelled cloud, as the browser's camera sees it
    cam = ScreenCamera.from_viser(sess.client.camera)
    lab = np.flatnonzero(d.seg.instance >= 0)
    u, v, z = cam.project(d.seg.points[lab])
    ok = (z > 0) & (u > 0.2) & (u < 0.8) & (v > 0.2) & (v < 0.8)
    assert ok.any(), "no labelled point in the middle of the view"
    j = lab[ok][np.argmin(np.hypot(u[ok] - np.median(u[ok]), v[ok] - np.median(v[ok])))]
    uj, vj, _ = cam.project(d.seg.points[j:j + 1])
    shown = np.zeros(len(d.seg.points), bool)
    shown[sess.lod_idx] = True
    want = pick_along_ray(d.seg.points, *cam.ray(float(uj[0]), float(vj[0])), candidates=shown)
    assert want >= 0
    box = page.locator("canvas").first.bounding_box()
    page.keyboard.down("Alt")  # Alt+click: a plain click is the Edit tab's selection
    page.mouse.click(box["x"] + float(uj[0]) * box["width"], box["y"] + float(vj[0]) * box["height"])
    page.keyboard.up("Alt")
    _wait(lambda: ep.sv_result is not None, what="the click's super-voxel explanation", timeout=20)
    got = ep.sv_result.k
    # the ray the page sent hits the same surface: the same super-voxel or a touching one
    pts = d.seg.points
    near = np.linalg.norm(pts[d.seg.sv_labels == got] - pts[want], axis=1).min()
    assert got == int(d.seg.sv_labels[want]) or near < 0.02, (got, int(d.seg.sv_labels[want]), near)
    page.get_by_text(f"super-voxel {got}:").first.wait_for(timeout=10_000)
    if ep.sv_result.tally:
        assert page.get_by_text(f"group {ep.sv_result.tally[0].group}: vote").count() >= 1
    page.get_by_text(f"super-voxel {got}:").first.scroll_into_view_if_needed()
    time.sleep(1.0)
    page.screenshot(path=str(artifacts / "explain_why_here.png"))
    page.close()
