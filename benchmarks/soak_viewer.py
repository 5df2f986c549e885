"""Soak benchmark: the viewer serving one run to 5 browser tabs for N minutes while scripted clients act.

    .venv/bin/python benchmarks/soak_viewer.py [--minutes 10] [--tabs 5] [--clients chromium|ws]
                                               [--workdir /tmp/clutt3r-soak] [--out docs/img/soak]

What runs:
- a generated run (``clutt3r synth --preset intermediate --seed 0 --width 448 --height 336``,
  8 views, segmented with the builtin masks: < 100k points), served by ``clutt3r_viewer.start``
  on 127.0.0.1 (a copy of the run, so its corrections log starts empty);
- ``--tabs`` clients connected to it: real pages in one headless Debian chromium
  (``--clients chromium``, software WebGL: every update is also rendered), or raw websocket
  clients that receive and discard every message (``--clients ws``: the server does the same
  work, no rendering; for a machine too small for the pages);
- a scripted loop that, until the deadline, picks a tab and one action:
  switch view (``Session.select_view``), replay a step (``ReplayPanel.set_event``), query
  (``QueryPanel.run_query``; only when the viewer has a text embedder, else skipped and said),
  colour layer, or edit (``ViewerApp.edit_run`` with an Edit-tab ``selection_op`` on a few random
  super-voxels: the Edit tab's own code path). The actions are called server-side, as the
  panels' callbacks call them (viser runs those in its threads; we call them from this one), so
  the handler time is measured exactly; with chromium the page round trip (action start until
  that page received a websocket frame afterwards) is measured too.

Reported (stdout, and ``--out``.json / .png): the server process's RSS every 5 s (and the
chromium processes' total), the handler latency per action kind (median, p99, max), the page round
trip, the 1-minute load average, and the edit check: every edit ``edit_run`` acknowledged is in
``corrections/ops.jsonl`` at the end, in order, and replaying the log gives the live labels.
Bounded: the loop ends at the deadline; every wait has a timeout; localhost only.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import shutil
import subprocess
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from clutt3r_viewer.headless import CHROMIUM, CHROMIUM_ARGS, free_port

ROOT = Path(__file__).resolve().parents[1]
QUERIES = ["the red mug", "a yellow box", "the bottle", "blue thing", "banana", "the can"]


def _rss_mb(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return 0.0


def _children_rss_mb(pid: int) -> float:
    """Total RSS of every descendant of ``pid`` (the chromium processes playwright started)."""
    import psutil

    try:
        return sum(c.memory_info().rss for c in psutil.Process(pid).children(recursive=True)) / 2**20
    except psutil.Error:
        return 0.0


def make_run(workdir: Path) -> Path:
    """The generated run (cached in ``workdir``) and a fresh copy of it to serve and edit."""
    scene, run = workdir / "scene", workdir / "run"
    cli = [sys.executable, "-m", "clutt3r_core"]
    if not (run / "instances.npz").is_file():
        shutil.rmtree(workdir, ignore_errors=True)
        subprocess.run([*cli, "synth", "--out", str(scene), "--preset", "intermediate", "--seed", "0",
                        "--width", "448", "--height", "336"], check=True)
        subprocess.run([*cli, "segment", str(scene), "--out", str(run)], check=True)
    served = workdir / "served"
    shutil.rmtree(served, ignore_errors=True)
    shutil.copytree(run, served)
    return served


def camera_message() -> bytes:
    """A browser's first camera message, as viser's client sends it (msgpack of the message's dict)."""
    import msgspec
    from viser import _messages

    msg = _messages.ViewerCameraMessage(wxyz=(1.0, 0.0, 0.0, 0.0), position=(0.0, 0.0, 1.0), fov=1.0, near=0.01,
                                        far=100.0, image_height=800, image_width=1280, look_at=(0.0, 0.0, 0.0),
                                        up_direction=(0.0, 0.0, 1.0))
    return msgspec.msgpack.encode(msg.as_serializable_dict())


class WsClients:
    """``n`` websocket clients speaking viser's subprotocol that read and discard every message."""

    def __init__(self, url: str, n: int) -> None:
        import viser

        self.url = url.replace("http://", "ws://")
        self.proto = f"viser-v{viser.__version__}"
        self.n = n
        self.bytes = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=lambda: asyncio.run(self._main()), daemon=True)
        self.thread.start()

    async def _one(self) -> None:
        import websockets

        async with websockets.connect(self.url, subprotocols=[self.proto], max_size=None) as ws:
            await ws.send(camera_message())  # viser counts a client as connected at its first camera message
            while not self.stop.is_set():
                try:
                    msg = await asyncio.wait_for(ws.recv(), timeout=0.5)
                    self.bytes += len(msg)
                except asyncio.TimeoutError:
                    pass

    async def _main(self) -> None:
        await asyncio.gather(*(self._one() for _ in range(self.n)), return_exceptions=True)

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--minutes", type=float, default=10.0)
    ap.add_argument("--tabs", type=int, default=5)
    ap.add_argument("--clients", choices=["chromium", "ws", "mixed"], default="chromium",
                    help="mixed: one chromium page (page round trips), the other tabs websocket clients")
    ap.add_argument("--workdir", type=Path, default=Path("/tmp/clutt3r-soak"))
    ap.add_argument("--out", type=Path, default=None, help="write OUT.json and OUT.png (RSS over time)")
    ap.add_argument("--pause", type=float, default=0.2, help="seconds between actions (a user's pace is slower)")
    ap.add_argument("--seed", type=int, default=0)
    a = ap.parse_args()

    import clutt3r_viewer
    from clutt3r_core.annotations import Annotations, apply
    from clutt3r_viewer.edit import selection_op
    from clutt3r_viewer.panels import QueryPanel, ReplayPanel

    run = make_run(a.workdir)
    app = clutt3r_viewer.start(run, port=free_port())
    n_points = len(app.data.seg.points)
    print(f"serving {run} ({n_points:,} points, {len(app.data.views)} views) at {app.url} to {a.tabs} "
          f"{a.clients} tabs for {a.minutes:g} min", flush=True)
    rng = np.random.default_rng(a.seed)
    pw = browser = ws = None
    pages: dict[int, object] = {}  # client id -> page
    frames: dict[int, int] = {}  # id(page) -> websocket frames received
    try:
        n_pages = {"chromium": a.tabs, "mixed": 1, "ws": 0}[a.clients]
        if n_pages:
            from playwright.sync_api import sync_playwright

            pw = sync_playwright().start()
            browser = pw.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
            for _ in range(n_pages):
                before = set(app.sessions)
                page = browser.new_page(viewport={"width": 1280, "height": 800})
                frames[id(page)] = 0

                def on_ws(w, key=id(page)):
                    def rx(_payload):
                        frames[key] += 1
                    w.on("framereceived", rx)

                page.on("websocket", on_ws)
                page.goto(app.url)
                t = time.time()
                while not set(app.sessions) - before and time.time() - t < 300:
                    page.wait_for_timeout(50)
                new = set(app.sessions) - before
                if not new:
                    raise TimeoutError("a chromium tab did not connect within 300 s")
                pages[new.pop()] = page
        if a.tabs > n_pages:
            ws = WsClients(app.url, a.tabs - n_pages)
        sessions = app.wait_for_sessions(a.tabs, timeout=300)
        print(f"{len(sessions)} tabs connected and built (build {max(s.build_seconds for s in sessions):.1f} s max)",
              flush=True)
        can_query = all(s.panel(QueryPanel) is not None for s in sessions) and app.text_embedder is not None
        lang = None
        if not can_query and all(s.panel(QueryPanel) is not None for s in sessions):
            from clutt3r_viewer.panels.query import language_backend_name

            lang = language_backend_name()
            can_query = lang is not None
        kinds = ["view", "replay", "colour", "edit"] + (["query"] if can_query else [])
        print("actions: " + ", ".join(kinds) + ("" if can_query else " (query skipped: the viewer has no text "
                                                                        "embedder on this machine)"), flush=True)

        warmup = None
        if lang is not None:  # the first query describes every view's masks (a one-off): timed apart
            t0 = time.perf_counter()
            sessions[0].panel(QueryPanel)._run_query_object(sessions[0])
            warmup = time.perf_counter() - t0
            print(f"first query's mask description ({lang}): {warmup:.1f} s (not in the soak figures)", flush=True)
        pid = os.getpid()
        t_start = time.perf_counter()
        deadline = t_start + a.minutes * 60
        samples: list[tuple[float, float, float, float]] = []  # (t s, server RSS MB, chromium RSS MB, load1)
        lat: dict[str, list[float]] = {k: [] for k in kinds}
        trip: dict[str, list[float]] = {k: [] for k in kinds}
        slowest = (0.0, "", 0.0)
        acked: list = []  # the ops edit_run acknowledged, in order
        refused = 0
        next_sample = 0.0
        step = 0
        sv = app.data.seg.sv_labels
        while time.perf_counter() < deadline:
            now = time.perf_counter() - t_start
            if now >= next_sample:
                samples.append((now, _rss_mb(pid), _children_rss_mb(pid) if pw else 0.0, os.getloadavg()[0]))
                next_sample += 5.0
            sessions = [s for s in app.sessions.values() if s.built and not s.closed]
            if len(sessions) < a.tabs:
                raise RuntimeError(f"a tab went away: {len(sessions)} of {a.tabs} left at {now:.0f} s")
            s = sessions[step % len(sessions)]
            kind = kinds[int(rng.integers(0, len(kinds)))]
            page = pages.get(s.client.client_id)
            f0 = frames.get(id(page), 0)
            t0 = time.perf_counter()
            if kind == "view":
                s.select_view(int(rng.integers(0, len(app.data.trace.frames))))
            elif kind == "replay":
                rp = s.panel(ReplayPanel)
                src = s.replay_source()
                rp.set_event(s, int(rng.integers(0, max(src.num_events, 1) + 1)) if src is not None else 0)
            elif kind == "colour":
                s.set_color_mode(["instance", "rgb", "confidence"][int(rng.integers(0, 3))])
            elif kind == "query":
                s.panel(QueryPanel).run_query(s, QUERIES[int(rng.integers(0, len(QUERIES)))])
            else:  # edit: the Edit tab's selection ops on 3 random super-voxels
                sel = np.isin(sv, rng.integers(0, sv.max() + 1, 3))
                op_kind = ("new", "assign", "merge", "delete", "split")[int(rng.integers(0, 5))]
                alive = app.annotations.current.alive
                target = int(rng.choice(alive)) if len(alive) else -1
                made: list = []

                def action(ann, op_kind=op_kind, sel=sel, target=target, made=made):
                    op = selection_op(op_kind, ann.base, ann.current, sel, target)
                    made.append(op)
                    return ann.apply_op(op)

                if app.edit_run(action, s):
                    acked.append(made[-1])
                else:
                    refused += 1
            dt = time.perf_counter() - t0
            lat[kind].append(dt)
            if dt > slowest[0]:
                slowest = (dt, kind, now)
            if page is not None:  # page round trip: until this page received a frame sent after the action
                t_end = time.perf_counter() + 30
                while frames[id(page)] == f0 and time.perf_counter() < t_end:
                    page.wait_for_timeout(5)
                if frames[id(page)] > f0:
                    trip[kind].append(time.perf_counter() - t0)
            step += 1
            if step % 200 == 0:
                print(f"{now / 60:.1f} min: {step} actions, RSS {samples[-1][1]:.0f} MB, load {samples[-1][3]:.1f}",
                      flush=True)
            if pages:
                next(iter(pages.values())).wait_for_timeout(int(a.pause * 1000))  # pumps the pages' events
            else:
                time.sleep(a.pause)
        samples.append((time.perf_counter() - t_start, _rss_mb(pid), _children_rss_mb(pid) if pw else 0.0,
                        os.getloadavg()[0]))
        n_tabs_end = len([s for s in app.sessions.values() if not s.closed])
    finally:
        ann_live = app.annotations.current if app.annotations is not None else None
        app.stop()  # closes the log (every edit is already in it)
        if browser is not None:
            browser.close()
        if pw is not None:
            pw.stop()
        if ws is not None:
            ws.close()

    # every acknowledged edit is in the log, in order; the log replays to the live labels
    fresh = Annotations.open(run, readonly=True)
    logged = list(fresh.ops)
    # the log holds each op as built, with the session's author filled in by apply_op
    same = [x == replace(y, author=y.author or x.author) for x, y in zip(logged, acked)]
    in_log = len(logged) == len(acked) and all(same)
    first_diff = next((i for i, ok in enumerate(same) if not ok), None)
    replays = apply(fresh.base, fresh.ops).equals(ann_live) and fresh.current.equals(ann_live)

    def stats(v: list[float]) -> dict:
        if not v:
            return {"n": 0}
        x = np.asarray(v) * 1e3
        return {"n": len(v), "median_ms": round(float(np.median(x)), 1), "p99_ms": round(float(np.percentile(x, 99)), 1),
                "max_ms": round(float(x.max()), 1)}

    rss = np.array([r[1] for r in samples])
    out = {
        "minutes": a.minutes, "tabs": a.tabs, "clients": a.clients, "points": n_points, "actions": step,
        "tabs_at_end": n_tabs_end, "query_warmup_s": None if warmup is None else round(warmup, 1),
        "query": "language backend " + lang if lang else ("run's text embedder" if can_query else "skipped"),
        "handler": {k: stats(v) for k, v in lat.items()},
        "round_trip": {k: stats(v) for k, v in trip.items()} if pages else None,
        "slowest": {"ms": round(slowest[0] * 1e3, 1), "action": slowest[1], "at_s": round(slowest[2], 1)},
        "rss_mb": {"start": round(float(rss[0]), 1), "end": round(float(rss[-1]), 1), "max": round(float(rss.max()), 1),
                   "after_1min": round(float(rss[min(12, len(rss) - 1)]), 1)},
        "chromium_rss_mb": {"start": round(samples[0][2], 1), "end": round(samples[-1][2], 1)} if pw else None,
        "load1": {"min": round(min(r[3] for r in samples), 2), "max": round(max(r[3] for r in samples), 2),
                  "mean": round(float(np.mean([r[3] for r in samples])), 2)},
        "edits": {"acknowledged": len(acked), "refused": refused, "in_log": len(logged),
                  "all_acknowledged_in_log_in_order": bool(in_log),
                  "first_difference": None if first_diff is None else [repr(logged[first_diff]), repr(acked[first_diff])], "log_replays_to_live_labels": bool(replays)},
        "samples": [[round(t, 1), round(r, 1), round(c, 1), round(ld, 2)] for t, r, c, ld in samples],
    }
    print(json.dumps({k: v for k, v in out.items() if k != "samples"}, indent=1))
    if a.out is not None:
        a.out.parent.mkdir(parents=True, exist_ok=True)
        a.out.with_suffix(".json").write_text(json.dumps(out, indent=1))
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 3), dpi=100)
        t = np.array([r[0] for r in samples]) / 60
        ax.plot(t, rss, label="viewer server (python) RSS")
        if pw:
            ax.plot(t, [r[2] for r in samples], label="chromium (all processes) RSS")
        ax.set_xlabel("minutes")
        ax.set_ylabel("MB")
        ax.set_ylim(bottom=0)
        ax.set_title(f"soak: {a.tabs} {a.clients} tabs, {n_points:,} points, {step} actions", fontsize=9)
        ax2 = ax.twinx()
        ax2.plot(t, [r[3] for r in samples], color="grey", lw=0.8, ls=":", label="load average (1 min)")
        ax2.set_ylabel("load avg", color="grey")
        ax2.set_ylim(bottom=0)
        h1, l1 = ax.get_legend_handles_labels()
        h2, l2 = ax2.get_legend_handles_labels()
        ax.legend(h1 + h2, l1 + l2, fontsize=7, loc="lower right")
        fig.tight_layout()
        fig.savefig(a.out.with_suffix(".png"))
        print(f"-> {a.out.with_suffix('.json')}, {a.out.with_suffix('.png')}")
    if not (in_log and replays):
        sys.exit("edit check failed: an acknowledged edit is missing from the log or the log does not replay")


if __name__ == "__main__":
    main()
