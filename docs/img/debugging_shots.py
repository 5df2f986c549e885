"""Regenerate the screenshots of docs/debugging.md (headless chromium, Debian /usr/bin/chromium).

    .venv/bin/clutt3r segment /work/shared/data/clutt3r-samples/sample_seq4/data --out /tmp/seq4run
    .venv/bin/python docs/img/debugging_shots.py /tmp/seq4run 0:3 1:11

Drives the Explain tab like a user (types the two masks, presses "Why not?", jumps the
replay, Alt+clicks a point for "Why here?") and writes small PNGs (palette, < 300 KB) here.
"""

from __future__ import annotations

import io
import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image
from playwright.sync_api import sync_playwright

import clutt3r_viewer
from clutt3r_viewer.headless import CHROMIUM, CHROMIUM_ARGS, free_port
from clutt3r_viewer.panels import ExplainPanel
from clutt3r_viewer.selection import ScreenCamera

OUT = Path(__file__).resolve().parent


def save(png: bytes, name: str, width: int = 1000) -> None:
    img = Image.open(io.BytesIO(png)).convert("RGB")
    if img.width > width:
        img = img.resize((width, round(img.height * width / img.width)), Image.LANCZOS)
    img.quantize(colors=128, method=Image.Quantize.MEDIANCUT).save(OUT / name, optimize=True)
    print(name, (OUT / name).stat().st_size, "bytes")


def wait(pred, timeout=30.0):
    t0 = time.time()
    while not pred():
        if time.time() - t0 > timeout:
            raise TimeoutError
        time.sleep(0.1)


def main(run: str, a: str, b: str) -> None:
    app = clutt3r_viewer.start(run, port=free_port())
    with sync_playwright() as pw:
        br = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        page = br.new_page(viewport={"width": 1400, "height": 860})
        page.goto(app.url)
        page.wait_for_selector("canvas", timeout=60_000)
        sess = app.wait_for_sessions(1, timeout=120)[0]
        time.sleep(3)
        page.set_default_timeout(120_000)  # software WebGL with 150k points: every frame is slow
        page.get_by_role("tab", name="Explain").click(no_wait_after=True)
        ep = sess.panel(ExplainPanel)
        boxes = page.get_by_role("textbox").locator("visible=true")
        for k, v in ((0, a), (1, b)):
            boxes.nth(k).fill(v)
            boxes.nth(k).press("Enter")
        wait(lambda: ep.mask_b.value == b)
        page.get_by_role("button", name="Why not?").click(no_wait_after=True)
        wait(lambda: ep.result is not None)
        page.get_by_text("fates diverged at replay step").first.scroll_into_view_if_needed()
        time.sleep(1.5)
        save(page.screenshot(), "debug_why_not.png")
        page.get_by_role("button", name=f"Replay: go to step {ep.result.diverge_step}").click(no_wait_after=True)
        wait(lambda: sess.state.event == ep.result.diverge_step)
        page.get_by_role("tab", name="Replay").click(no_wait_after=True)
        page.get_by_text("masks of this step").first.scroll_into_view_if_needed()
        time.sleep(2.5)
        save(page.screenshot(), "debug_replay.png")
        # Why here: Alt+click the point of mask A's super-voxel that is nearest the screen centre
        page.get_by_role("tab", name="Explain").click(no_wait_after=True)
        page.locator("input[value='nothing']").first.click(no_wait_after=True)
        page.get_by_role("option", name="super-voxel").click(no_wait_after=True)
        wait(lambda: ep.pick.value == "super-voxel")
        d = app.data
        cam = ScreenCamera.from_viser(sess.client.camera)
        pts = d.seg.points[d.seg.instance == ep.result.instance_a]
        u, v, z = cam.project(pts)
        j = int(np.argmin(np.hypot(u - np.median(u), v - np.median(v))))
        box = page.locator("canvas").first.bounding_box()
        page.keyboard.down("Alt")
        page.mouse.click(box["x"] + u[j] * box["width"], box["y"] + v[j] * box["height"])
        page.keyboard.up("Alt")
        wait(lambda: ep.sv_result is not None)
        page.get_by_text(f"super-voxel {ep.sv_result.k}:").first.scroll_into_view_if_needed()
        time.sleep(1.5)
        save(page.screenshot(), "debug_why_here.png")
        print(ep.result.text())
        print(ep.sv_result.text())
        br.close()
    app.stop()


if __name__ == "__main__":
    main(*sys.argv[1:4])
