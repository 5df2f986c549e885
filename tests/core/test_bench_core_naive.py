"""benchmarks/bench_core.py's naive (pre-optimisation) core still runs against today's core.

The benchmark patches old implementations into the core with ``unittest.mock`` and checks
every output equal; when a core function moves or changes its types the patch silently
stops applying (support.py took ``fit_plane_ransac`` from supervoxels) or the run breaks
(``VoxelHits`` replaced scipy's CSR, ``MaskCandidates`` became compact). This keeps the
harness honest on a tiny scene; the timings stay in the benchmark.
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from clutt3r_core.pipeline import segment
from tests.core._tiny_run import tiny_scene, tiny_segmentation

_PATH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_core.py"


def _bench_core():
    spec = importlib.util.spec_from_file_location("bench_core", _PATH)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_naive_core_patches_apply_and_match_the_fast_core():
    bc = _bench_core()
    import clutt3r_core.support as support

    with bc.naive_core():
        # every patched name must exist where the core looks it up (mock.patch would
        # create nothing, but a moved function would leave the patch unused)
        assert support.fit_plane_ransac is bc._naive_fit_plane_ransac
        naive = segment(tiny_scene())
    ok, diffs = bc.compare(tiny_segmentation(), naive)
    assert ok, diffs
