"""``clutt3r view``, ``clutt3r export-rerun`` and ``clutt3r demo`` (entry-point group ``clutt3r.commands``)."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from tyro.conf import Positional

__all__ = ["view_command", "export_rerun_command", "demo_command"]


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
    out: Path = Path("runs/demo"),
    port: int = 8080,
    seed: int = 0,
    preset: str = "intermediate",
) -> None:
    """Generate a synthetic scene, segment it, save the run and open it in the viewer.

    Args:
        out: run folder to write; the scene goes to OUT/scene.
        port: port of the web server (http://127.0.0.1:PORT).
        seed: random seed of the generated scene.
        preset: clutter level of the scene: easy, intermediate or hard.
    """
    from clutt3r_viewer import serve

    run = make_demo_run(out, seed=seed, preset=preset)
    serve(run, port=port)


def make_demo_run(out: Path, seed: int = 0, preset: str = "intermediate", views: int = 8,
                  width: int = 640, height: int = 480, focal_px: float | None = None) -> Path:
    """Generate + segment + save (the demo without the server). Returns the run folder."""
    from clutt3r_core.pipeline import segment
    from clutt3r_core.runs import save_run
    from clutt3r_core.synth import SynthConfig, generate, write_synth_scene

    out = Path(out)
    kw = {} if focal_px is None else {"focal_px": focal_px}
    cfg = SynthConfig(seed=seed, preset=preset, views=views, width=width, height=height, **kw)
    print(f"generating a synthetic '{preset}' scene (seed {seed}, {views} views) ...", flush=True)
    res = generate(cfg, progress=False)
    scene_dir = write_synth_scene(res.scene, out / "scene", info=res.info, contact_sheet=False)
    print("segmenting ...", flush=True)
    seg = segment(res.scene)
    save_run(seg, out, scene_root=scene_dir)  # run.json records the scene (relative: scene/)
    print(f"{out}: {seg.num_instances} instances ({len(res.info.object_keys)} objects in the scene)", flush=True)
    return out
