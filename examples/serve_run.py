"""Serve a run in the Clutt3R viewer from Python.

    .venv/bin/python examples/serve_run.py runs/demo            # a saved run folder
    .venv/bin/python examples/serve_run.py path/to/scene        # a scene: segmented in the page's background

Then open http://127.0.0.1:8080. Equivalent to `clutt3r view PATH`.
"""

import sys

import clutt3r_viewer
from clutt3r_core.pipeline import load_run

if __name__ == "__main__":
    path = sys.argv[1] if len(sys.argv) > 1 else "runs/demo"
    try:
        run = load_run(path)  # a Segmentation object works as well as a folder
        clutt3r_viewer.serve(run, port=8080, scene=clutt3r_viewer.loading.find_scene(__import__("pathlib").Path(path)))
    except Exception:
        clutt3r_viewer.serve(path, port=8080)
