"""What a ``clutt3r segment`` process imports (issue 13: the whole command, not only the core).

``import open3d`` costs about 0.9 s per process (its package init loads its plotly/dash
visualisation) and building the whole command table imports every command's module; the
segment command needs neither. Checked in fresh subprocesses, since this test process has
imported half the project already.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from clutt3r_core.io import write_sample_layout
from tests.core.robustness._scenes import make_scene

# never needed to segment a scene: other commands' packages and open3d's visualisation
# (scipy.spatial and scipy.sparse.csgraph, which loads scipy.linalg: 0.1-0.2 s of package
# init each; the k-NN queries are pykdtree's, the super-voxels' components our own;
# scipy.sparse, 0.17-0.19 s: the mask-voxel hits are occupancy.VoxelHits, issue 13)
_FORBIDDEN = ("open3d", "dash", "plotly", "clutt3r_viewer", "clutt3r_core.evaluation", "clutt3r_core.grasping",
              "clutt3r_core.synth", "clutt3r_core.update", "clutt3r_core.baselines", "scipy.spatial",
              "scipy.sparse", "scipy.linalg",
              # tyro checks X | None defaults with typeguard (50-100 ms with unittest.mock, asyncio)
              "typeguard", "asyncio")


def _modules_after(code: str, *args: str) -> tuple[subprocess.CompletedProcess, list[str]]:
    """Run ``code`` in a fresh interpreter; the top-level names of sys.modules at exit."""
    prog = (
        "import atexit, json, sys\n"
        "atexit.register(lambda: sys.__stdout__.write('MODULES=' + json.dumps(sorted(sys.modules)) + '\\n'))\n"
        + code
    )
    r = subprocess.run([sys.executable, "-c", prog, *args], capture_output=True, text=True, timeout=300)
    line = [x for x in r.stdout.splitlines() if x.startswith("MODULES=")]
    assert line, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    return r, json.loads(line[-1][len("MODULES="):])


def _loaded(mods: list[str], name: str) -> bool:
    return any(m == name or m.startswith(name + ".") for m in mods)


def test_importing_the_pipeline_does_not_import_open3d():
    r, mods = _modules_after("import clutt3r_core.pipeline, clutt3r_core.commands.segment, clutt3r_core.io")
    assert r.returncode == 0, r.stderr
    assert [f for f in _FORBIDDEN if _loaded(mods, f)] == []


def test_segment_command_process_imports_only_what_it_uses(tmp_path: Path):
    scene = write_sample_layout(make_scene(3, width=160, height=120), tmp_path / "scene")
    r, mods = _modules_after(
        "from clutt3r_core.cli import main\nmain(sys.argv[1:])\n",
        "segment", str(scene), "--out", str(tmp_path / "run"),
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "run" / "instances.npz").is_file()
    assert [f for f in _FORBIDDEN if _loaded(mods, f)] == []
    # the modules it does need were loaded (the check above is not vacuous)
    assert _loaded(mods, "pykdtree") and _loaded(mods, "clutt3r_core.pipeline")


def test_the_command_table_still_answers_without_a_command(capsys):
    """``clutt3r --help`` and an unknown name go through the whole table (every command listed)."""
    from clutt3r_core.cli import main

    for args in (["--help"], ["no-such-command"]):
        try:
            main(args)
        except SystemExit:
            pass
        out = capsys.readouterr()
        text = out.out + out.err
        assert "segment" in text and "synth" in text, text[-500:]


def _blas_threads_after(env_extra: dict[str, str]) -> int:
    """numpy's BLAS thread count after a fresh ``clutt3r segment --help`` process."""
    import os

    prog = (
        "import atexit, sys\n"
        "from threadpoolctl import threadpool_info\n"
        "atexit.register(lambda: sys.__stdout__.write('BLAS=%d\\n' % max(i['num_threads'] for i in threadpool_info()"
        " if i['user_api'] == 'blas')))\n"
        "from clutt3r_core.cli import main\n"
        "main(['segment', '--help'])\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")}
    r = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, timeout=300, env={**env, **env_extra})
    line = [x for x in r.stdout.splitlines() if x.startswith("BLAS=")]
    assert line, (r.returncode, r.stdout[-2000:], r.stderr[-2000:])
    return int(line[-1][5:])


def test_the_cli_runs_blas_on_one_thread_unless_the_user_chose():
    """Issue 13: OpenBLAS's worker threads only spin on the pipeline's small products (1 s of CPU
    of 4 on a hard scene); a thread count the user set in the environment is kept."""
    assert _blas_threads_after({}) == 1
    assert _blas_threads_after({"OPENBLAS_NUM_THREADS": "2"}) == 2
