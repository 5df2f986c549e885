"""Serve a run in the Clutt3R viewer from Python.

    .venv/bin/python examples/serve_run.py runs/demo                 # a saved run folder (its images too:
                                                                     # the run recorded its scene folder)
    .venv/bin/python examples/serve_run.py runs/demo scenes/moved    # the same run, scene folder given
    .venv/bin/python examples/serve_run.py path/to/scene             # a scene: segmented in the page's background

Then open http://127.0.0.1:8080. Equivalent to `clutt3r view PATH [--scene SCENE]`.
"""

import sys

import clutt3r_viewer

if __name__ == "__main__":
    path = sys.argv[1] if len(sys.argv) > 1 else "runs/demo"
    scene = sys.argv[2] if len(sys.argv) > 2 else None  # overrides the scene folder the run recorded
    clutt3r_viewer.serve(path, port=8080, scene=scene)
