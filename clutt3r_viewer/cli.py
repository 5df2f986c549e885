"""``clutt3r view``, ``clutt3r export-rerun``, ``clutt3r export-html`` and ``clutt3r demo`` (entry-point group
``clutt3r.commands``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from tyro.conf import Positional

__all__ = ["view_command", "export_rerun_command", "demo_command", "export_html_command"]


def view_command(
    path: Positional[Path],
    port: int = 8080,
    host: str = "127.0.0.1",
    scene: Path | None = None,
    lod: Literal["50k", "200k", "1M", "all"] = "200k",
    no_images: bool = False,
) -> None:
    """Inspect a run (or segment a scene and inspect it) in the browser.

    Args:
        path: a run folder (`clutt3r segment` output; nothing is recomputed) or a scene folder
            (segmented on the fly, progress shown in the page).
        port: port of the web server.
        host: address to bind; 127.0.0.1 keeps it local.
        scene: the run's scene folder, for images and cameras (default: the one the run recorded in
            run.json, else viewer.json or scene/ in the run).
        lod: points sent to each browser tab at first (level of detail; changeable in the page).
        no_images: open the run without its scene (e.g. when its recorded scene folder moved).
    """
    import sys

    from clutt3r_viewer import serve

    if host not in ("127.0.0.1", "localhost", "::1"):  # issue 14: the page can edit the run's labels
        print(f"warning: serving on {host}:{port}: anyone who can reach this address on your network can view "
              "this run and edit its labels (omit --host to keep it on 127.0.0.1)", file=sys.stderr, flush=True)
    # typed errors (a damaged run, a moved scene folder) reach the CLI: one line, status 2, --debug (issue 14)
    serve(path, port=port, host=host, scene=scene, lod=lod, images=not no_images)


def export_rerun_command(run: Positional[Path], out: Positional[Path], scene: Path | None = None, max_points: int = 50_000) -> None:
    """Write a run's trace to a rerun recording (.rrd): views, masks, grouping steps, instances.

    Args:
        run: run folder.
        out: the .rrd file to write.
        scene: the run's scene folder (default: the one recorded in run.json, else viewer.json or scene/ in
            the run); without it no images.
        max_points: points of the per-event replay cloud.
    """
    import sys

    from clutt3r_core.errors import Clutt3rError
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.rerun_export import export_rerun

    try:
        data = load_viewer_data(run, scene)
    except Clutt3rError as e:
        print(f"clutt3r export-rerun: {e}", file=sys.stderr)
        raise SystemExit(2) from None
    p = export_rerun(data, out, max_points=max_points)
    print(f"{p}: {p.stat().st_size / 1e6:.1f} MB ({len(data.views)} views, {data.num_events} grouping events, "
          f"{data.seg.num_instances} instances)")


def demo_command(
    out: Path | None = None,
    port: int = 8080,
    seed: int = 1,
    preset: str = "intermediate",
    scene: Path | None = None,
    rebuild: bool = False,
) -> None:
    """The whole story in one command: a pre/post scene segmented, queried, grasped and updated,
    served with a guided tour (docs/demo.md).

    Args:
        out: run folder to write (default runs/demo, or runs/demo_NAME for --scene); a generated
            scene goes to OUT/scene. A second demo on the same folder reuses it (OUT/demo.json).
        port: port of the web server (http://127.0.0.1:PORT).
        seed: random seed of the generated scene (1: the update finds both the removed and the
            pushed object, docs/demo.md).
        preset: clutter level of the generated scene: easy, intermediate or hard.
        scene: a scene folder (e.g. a real sample) instead of a generated one; its post-interaction
            frames (without depth, or listed as post frames) are the update.
        rebuild: recompute everything even when OUT/demo.json matches.
    """
    import threading
    import time

    from clutt3r_core.demo import DEMO_JSON, DemoConfig, build_demo, complete_demo
    from clutt3r_viewer import serve_until_interrupted, start
    from clutt3r_viewer.panels.tour import attach_story

    t0 = time.perf_counter()
    if out is None:
        out = Path("runs") / ("demo" if scene is None else f"demo_{Path(scene).resolve().name}")
    cfg = DemoConfig(scene=scene, seed=seed, preset=preset)
    if rebuild:
        (Path(out) / DEMO_JSON).unlink(missing_ok=True)
    story = build_demo(out, cfg, with_query=False)  # the query stages run while the first steps are shown
    app = start(out, port=port)
    attach_story(app, story)
    print(f"Clutt3R demo: {app.url}  (tour ready {time.perf_counter() - t0:.1f} s after the start; Ctrl-C to stop)",
          flush=True)
    if not story.complete:
        def finish() -> None:
            try:
                attach_story(app, complete_demo(out, cfg, story))
                print(f"query, grasps ready {time.perf_counter() - t0:.1f} s after the start", flush=True)
            except Exception as e:  # shown in the tour; the viewer keeps serving the rest
                attach_story(app, story, failed=f"{type(e).__name__}: {e}")
                raise

        threading.Thread(target=finish, daemon=True).start()
    serve_until_interrupted(app)


def make_demo_run(out: Path, seed: int = 1, preset: str = "intermediate", views: int = 8,
                  width: int = 640, height: int = 480, focal_px: float | None = None, query: bool = False) -> Path:
    """The demo's run without the server (``clutt3r_core.demo.build_demo``; ``query=False`` skips
    the query, its grasps and the mask description). Returns the run folder."""
    from clutt3r_core.demo import DemoConfig, build_demo

    kw = {} if focal_px is None else {"focal_px": focal_px}
    build_demo(out, DemoConfig(seed=seed, preset=preset, views=views, width=width, height=height, **kw),
               with_query=query)
    return Path(out)


def export_html_command(run: Positional[Path], out: Positional[Path], scene: Path | None = None,
                        max_points: int = 200_000) -> None:
    """Write a run as one standalone HTML page (cloud, instances, grasps) that opens without a server.

    Args:
        run: run folder.
        out: the .html file to write.
        scene: the run's scene folder, for the camera frustums (default: the one recorded in run.json).
        max_points: points embedded in the page.
    """
    from clutt3r_core.annotations import LOG_NAME, Annotations
    from clutt3r_viewer.export_html import export_html
    from clutt3r_viewer.loading import load_viewer_data

    # typed errors (a damaged run) reach the CLI: one line, status 2, --debug (issue 14)
    data = load_viewer_data(run, scene)
    labels = None
    if (Path(run) / LOG_NAME).is_file():  # the corrected labels, read-only
        with Annotations.open(run, segmentation=data.seg, readonly=True) as ann:
            labels = ann.current.instance if ann.num_ops else None
    p = export_html(data, out, labels, max_points=max_points)
    print(f"{p}: {p.stat().st_size / 1e6:.1f} MB ({data.seg.num_instances} instances, "
          f"{0 if data.grasps is None else len(data.grasps)} grasps); open it in a browser, no server needed")
