"""Screenshots of every guided-tour step (docs/img/tour/NN_key.jpg) from a demo run.

    .venv/bin/clutt3r demo --out runs/demo      # once (Ctrl-C after "query, grasps ready")
    .venv/bin/python scripts/tour_screenshots.py runs/demo docs/img/tour

Serves the run in-process, opens it in headless chromium (Debian's /usr/bin/chromium, through
playwright) at 1280x960, clicks Next through the tour and saves one page screenshot per step.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

from clutt3r_viewer.headless import CHROMIUM, CHROMIUM_ARGS, free_port



def main(run: str, out: str, settle: float = 4.0) -> None:
    from playwright.sync_api import sync_playwright

    import clutt3r_viewer
    from clutt3r_core.demo import load_story
    from clutt3r_viewer.panels.tour import TourPanel, attach_story
    from clutt3r_viewer.tour import STEPS

    story = load_story(run)
    if story is None:
        raise SystemExit(f"{run}: not a demo run (no demo.json); run `clutt3r demo --out {run}` first")
    app = clutt3r_viewer.start(run, port=free_port())
    attach_story(app, story)
    Path(out).mkdir(parents=True, exist_ok=True)
    try:
        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1280, "height": 960})
            page.goto(app.url)
            page.wait_for_selector("canvas", timeout=60_000)
            sess = app.wait_for_sessions(1, timeout=60)[0]
            tour = sess.panel(TourPanel)
            t0 = time.time()
            while tour.applied < 1 and time.time() - t0 < 60:
                time.sleep(0.1)
            time.sleep(2.0)
            # the "software WebGL" notice of headless chromium is not the subject: hide it
            page.add_style_tag(content="[class*='Notification-root']{display:none !important}")
            for k, step in enumerate(STEPS):
                if k:
                    n = tour.applied
                    page.get_by_role("button", name="Next").click()
                    t0 = time.time()
                    while tour.applied <= n and time.time() - t0 < 60:
                        time.sleep(0.1)
                time.sleep(settle)  # software WebGL: a few frames
                p = Path(out) / f"{k + 1:02d}_{step.key}.jpg"
                page.screenshot(path=str(p), quality=85)  # jpeg: ~0.15 MB a step
                print(p, flush=True)
            b.close()
    finally:
        app.stop()


if __name__ == "__main__":
    main(*sys.argv[1:3])
