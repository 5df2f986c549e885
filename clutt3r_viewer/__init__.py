"""Clutt3R inspection viewer: a run (or a scene, segmented on the fly) in the browser.

    import clutt3r_viewer
    clutt3r_viewer.serve("runs/demo", port=8080)     # a saved run folder, a scene folder,
                                                     # a Segmentation or a Scene

Reads only the core's public API (``clutt3r_core.pipeline``, ``Trace``); the core never
imports this package. viser is imported when a server starts.
"""

from __future__ import annotations

import time
from pathlib import Path

from clutt3r_viewer.data import GraspSet, UpdateFrame, ViewerData, build_viewer_data
from clutt3r_viewer.loading import load_viewer_data, register_update_loader, text_embedder_for

__all__ = [
    "serve",
    "serve_until_interrupted",
    "start",
    "ViewerData",
    "GraspSet",
    "UpdateFrame",
    "build_viewer_data",
    "load_viewer_data",
    "register_update_loader",
]


def start(
    run_or_scene,
    port: int = 8080,
    host: str = "127.0.0.1",
    scene=None,
    embedder=None,
    lod: str = "200k",
    verbose: bool = False,
    images: bool = True,
):
    """Start the viewer and return its ``ViewerApp`` at once (the server runs in threads).

    ``run_or_scene``: a run folder (``clutt3r segment`` output, read without recomputing),
    a scene folder or ``Scene`` (segmented in the background while the page shows progress),
    a ``Segmentation`` or a ``ViewerData``. ``scene`` adds images to a run (overriding the
    scene folder the run recorded); ``images=False`` opens a run without its scene (e.g. one
    whose recorded scene folder moved: otherwise a ``SceneFileError`` naming run.json);
    ``embedder`` overrides the text embedder used by the Query tab.
    """
    from clutt3r_core.errors import SceneFileError
    from clutt3r_core.pipeline import Segmentation
    from clutt3r_core.scene import Scene
    from clutt3r_viewer.app import ViewerApp
    from clutt3r_viewer.loading import is_run_dir, is_scene_dir

    if isinstance(run_or_scene, (str, Path)):  # refuse before the server starts (and prints its banner)
        from clutt3r_core.runs import RUN_FILES, missing_run_file

        p = Path(run_or_scene)
        if not is_run_dir(p) and not is_scene_dir(p):
            # a run folder with some of its files deleted: name the missing one (issue 14)
            missing = missing_run_file(p) if p.is_dir() else None
            if missing is not None and any((p / f).exists() for f in (*RUN_FILES, "run.json")):
                raise SceneFileError(missing, "missing: the run folder is incomplete (partly deleted?); "
                                     "segment the scene again")
            raise SceneFileError(p, "neither a run folder (instances.npz + trace/) nor a scene folder "
                                 "(transforms.json)")
    app = ViewerApp(None, host=host, port=port, lod=lod, verbose=verbose)

    def finish(data: ViewerData) -> ViewerData:
        app.text_embedder = text_embedder_for(data, embedder)
        return data

    def compute_scene(sc: Scene):
        def compute(report):
            from clutt3r_core.pipeline import segment

            report(f"segmenting {sc.name or 'scene'}: {len(sc.initial)} views")
            seg = segment(sc)
            report("preparing the viewer")
            return finish(build_viewer_data(seg, sc))

        return compute

    src = run_or_scene
    if isinstance(src, ViewerData):
        app.set_data(finish(src))
    elif isinstance(src, Segmentation):
        sc = scene
        if isinstance(sc, (str, Path)):
            from clutt3r_core.io import load_scene

            sc = load_scene(sc)
        app.set_data(finish(build_viewer_data(src, sc)))
    elif isinstance(src, Scene):
        app.compute_in_background(compute_scene(src))
    else:
        p = Path(src)
        if is_run_dir(p):
            from clutt3r_viewer.edit import open_annotations

            try:
                data = finish(load_viewer_data(p, scene, images=images))
                ann = open_annotations(p, data.seg)  # e.g. a log of another run: a clear error
            except BaseException:
                app.stop()
                raise
            if not images and not data.views:
                app.no_images_text = "_images not shown (`--no-images`)_"
            app.set_data(data, annotations=ann)
        elif is_scene_dir(p):
            from clutt3r_core.io import load_scene

            app.set_status(f"loading {p}")
            app.compute_in_background(compute_scene(load_scene(p)))
        else:
            app.stop()
            raise SceneFileError(p, "neither a run folder (instances.npz + trace/) nor a scene folder (transforms.json)")
    return app


def serve(run_or_scene, port: int = 8080, host: str = "127.0.0.1", scene=None, embedder=None, lod: str = "200k",
          images: bool = True):
    """Start the viewer (see ``start``), print its URL and serve until Ctrl-C."""
    app = start(run_or_scene, port=port, host=host, scene=scene, embedder=embedder, lod=lod, images=images)
    print(f"Clutt3R viewer: {app.url}  (Ctrl-C to stop)", flush=True)
    serve_until_interrupted(app)
    return app


def serve_until_interrupted(app) -> None:
    """Block until Ctrl-C, then stop the viewer's server (``serve`` and ``clutt3r demo``)."""
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
