"""Time from `clutt3r demo` to the tour's first step in a browser, and each stage (issue 16).

    .venv/bin/python benchmarks/bench_demo.py --out /tmp/demo_bench [--keep]

Runs the demo command as a user would (a fresh run folder unless --keep), reads its stage lines,
opens the printed URL in headless chromium and waits until the tour panel shows step 1; then
waits for the background stages (query evidence, suggested query, grasps). Prints one JSON
object: seconds to the server, to the tour's first step in the page, to "query, grasps ready",
and the stages from OUT/demo.json (wall and CPU seconds). The venv install is not counted.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

from clutt3r_viewer.headless import CHROMIUM, CHROMIUM_ARGS, free_port
from clutt3r_viewer.tour import STEPS


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/demo_bench")
    ap.add_argument("--keep", action="store_true", help="keep OUT (measure the cached second start)")
    ap.add_argument("--extra", nargs="*", default=[], help="more arguments for clutt3r demo")
    a = ap.parse_args()
    out = Path(a.out)
    if not a.keep:
        shutil.rmtree(out, ignore_errors=True)
    port = free_port()
    exe = Path(sys.executable).parent / "clutt3r"
    t0 = time.perf_counter()
    proc = subprocess.Popen([str(exe), "demo", "--out", str(out), "--port", str(port), *a.extra],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    res: dict = {}
    url = None
    lines = []
    try:
        for line in proc.stdout:
            lines.append(line.rstrip())
            m = re.search(r"Clutt3R demo: (http://\S+)", line)
            if m:
                url = m.group(1)
                res["server_s"] = round(time.perf_counter() - t0, 2)
                break
        if url is None:
            raise SystemExit("the demo did not start:\n" + "\n".join(lines))
        from playwright.sync_api import sync_playwright

        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1280, "height": 800})
            page.goto(url)
            page.get_by_text(STEPS[0].title).wait_for(timeout=120_000)  # the tour's step 1 is shown
            res["first_step_s"] = round(time.perf_counter() - t0, 2)
            b.close()
        deadline = time.time() + 600
        done = (out / "demo.json").is_file() and json.loads((out / "demo.json").read_text())["story"]["complete"]
        while not done:  # the background stages print this line when they finish
            line = proc.stdout.readline()
            lines.append(line.rstrip())
            if not line or "query, grasps ready" in line or time.time() > deadline:
                break
        res["query_ready_s"] = round(time.perf_counter() - t0, 2)
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    st = json.loads((out / "demo.json").read_text())["story"]
    res["stages"] = {s["stage"]: {"wall_s": round(s["seconds"], 2), "cpu_s": round(s.get("cpu_seconds", 0), 2)}
                     for s in st["stages"]}
    res["cached"] = a.keep
    print(json.dumps(res))


if __name__ == "__main__":
    main()
