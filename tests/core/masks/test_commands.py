"""``clutt3r masks`` and ``clutt3r segment --masks``: a scene without candidates segments with the
builtin generator, the run holds them in the sample layout's naming and names their generator."""

from __future__ import annotations

import dataclasses
import json

import pytest

from clutt3r_core.cli import main
from clutt3r_core.io import load_scene, write_sample_layout
from clutt3r_core.masks.formats import read_png_masks
from tests.core._tiny_run import tiny_scene

pytestmark = pytest.mark.filterwarnings("ignore:Got image with third dimension")


@pytest.fixture(scope="module")
def bare_scene(tmp_path_factory):
    """The tiny generated scene written without instance_masks/."""
    sc = tiny_scene()
    bare = dataclasses.replace(sc, views=tuple(dataclasses.replace(v, masks=None) for v in sc.views))
    root = tmp_path_factory.mktemp("bare") / "scene"
    write_sample_layout(bare, root)
    assert not (root / "instance_masks").exists()
    return root


def test_scene_without_masks_loads(bare_scene):
    sc = load_scene(bare_scene)
    assert all(v.masks is None for v in sc.views)


def test_masks_command_writes_sample_layout(bare_scene, tmp_path):
    out = tmp_path / "m"
    main(["masks", str(bare_scene), "--out", str(out)])
    sc = load_scene(bare_scene)
    for v in sc.initial_views:
        c = read_png_masks(out, v.frame, (v.camera.height, v.camera.width))
        assert len(c) >= 2
    # reusable as an import source
    main(["masks", str(bare_scene), "--out", str(tmp_path / "again"), "--masks", "import", "--mask-source", str(out)])
    assert sorted(p.name for p in out.iterdir()) == sorted(p.name for p in (tmp_path / "again").iterdir())


def test_segment_fills_missing_masks_and_records_generator(bare_scene, tmp_path):
    run = tmp_path / "run"
    main(["segment", str(bare_scene), "--out", str(run)])
    info = json.loads((run / "run.json").read_text())
    assert info["masks"] == {"generator": "builtin", "folder": "instance_masks", "generated": [0, 1, 2]}
    names = sorted(p.name for p in (run / "instance_masks").iterdir())
    assert names and all(n.startswith("mask_") and n.endswith(".png") for n in names)
    from clutt3r_core.runs import load_run

    seg = load_run(run)
    # the trace's leaves are the written candidates
    frames = {int(n.split("_")[1]) for n in names}
    assert set(seg.trace.frames.tolist()) == frames


def test_segment_auto_keeps_scene_masks(tmp_path):
    root = tmp_path / "scene"
    write_sample_layout(tiny_scene(), root)
    run = tmp_path / "run"
    main(["segment", str(root), "--out", str(run)])
    assert json.loads((run / "run.json").read_text())["masks"] == {"generator": "scene", "folder": None, "generated": []}
    assert not (run / "instance_masks").exists()


def test_run_masks_replace_the_scene_candidates_for_the_viewer(bare_scene, tmp_path):
    """What the viewer's loader does (clutt3r_viewer.loading.load_viewer_data calls with_run_masks)."""
    from clutt3r_core.masks import with_run_masks

    run = tmp_path / "run"
    main(["segment", str(bare_scene), "--out", str(run), "--masks", "builtin"])
    sc = with_run_masks(load_scene(bare_scene), run)
    from clutt3r_core.runs import load_run

    t = load_run(run).trace
    for v in sc.initial_views:
        assert v.masks is not None
        leaf_ids = set(t.nodes.mask_id[t.nodes.frame == v.frame].tolist())
        assert leaf_ids <= set(v.masks.ids.tolist())  # every node of the trace has its mask
    viewer = pytest.importorskip("clutt3r_viewer.loading")
    data = viewer.load_viewer_data(run)
    assert data is not None
