"""``clutt3r export-gt``: a corrected run becomes a benchmark scene folder (clutt3r_core.export_gt)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from clutt3r_core.annotations import Annotations, Merge, Relabel, SetCategory, Split
from clutt3r_core.errors import SceneFileError
from clutt3r_core.export_gt import ExportConfig, project_labels

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def corrected_run(tmp_path_factory):
    """A segmented synthetic scene (written in the sample layout) with a few corrections."""
    from clutt3r_core.io.sample_layout import write_sample_layout
    from clutt3r_core.pipeline import save_run, segment
    from clutt3r_core.synth import SynthConfig, generate_scene

    d = tmp_path_factory.mktemp("export")
    scene = generate_scene(SynthConfig(seed=0, preset="easy", views=3, width=160, height=120, n_objects=3),
                           progress=False)
    write_sample_layout(scene, d / "scene")
    seg = segment(scene)
    assert seg.num_instances >= 2
    save_run(seg, d / "run", scene_root=d / "scene")
    with Annotations.open(d / "run", segmentation=seg, author="t") as a:
        a.apply_op(Merge(0, 1))
        pts = np.flatnonzero(a.current.instance == 0)[:50]
        a.apply_op(Split(points=tuple(pts.tolist()), source=0))
        a.apply_op(SetCategory(0, "mug"))
        a.apply_op(Relabel(-1, points=tuple(np.flatnonzero(a.current.instance == 0)[:5].tolist())))
        labels = a.current
    return d, seg, labels


def test_export_scores_the_corrected_labels_at_ap_100_through_the_benchmark_folder_suite(corrected_run, tmp_path):
    from clutt3r_core.evaluation.metrics import evaluate_instances
    from clutt3r_core.evaluation.runner import folder_suite
    from clutt3r_core.io import load_scene

    d, seg, labels = corrected_run
    out = tmp_path / "gt_scene"
    r = subprocess.run([sys.executable, "-m", "clutt3r_core.cli", "export-gt", str(d / "run"), str(out)],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 0, r.stderr
    assert "objects" in r.stdout
    specs = folder_suite(out)  # what `clutt3r bench --scenes-dir` reads
    assert len(specs) == 1 and specs[0].path == str(out.resolve())
    gt = load_scene(specs[0].path).ground_truth
    inst, scores, cats = labels.compact()
    assert len(gt.objects) == len(scores) == int(inst.max()) + 1
    assert np.array_equal(gt.point_labels, inst) and np.allclose(gt.points, seg.points)
    assert gt.objects[0].category == "mug" and all(o.category == "object" for o in gt.objects[1:])
    ap, _ = evaluate_instances(seg.points, inst, scores, gt)
    assert ap.ap25 == ap.ap50 == ap.ap == 100.0  # percent
    # the uncorrected run is scored lower against the corrected truth (the edits matter)
    ap0, _ = evaluate_instances(seg.points, seg.instance, seg.scores, gt)
    assert ap0.ap < 100.0
    # per view: an instance map, and a COCO file whose RLE decodes to the same masks (our codec,
    # checked against pycocotools in the masks tests; pycocotools too when it is installed)
    from clutt3r_core.masks.formats import rle_decode, rle_string_decode

    try:
        from pycocotools import mask as mask_utils
    except ImportError:
        mask_utils = None
    for v in load_scene(out).views:
        m = gt.instance_maps[v.frame]
        assert m.shape == (v.camera.height, v.camera.width) and (m >= 0).any()
        coco = json.loads((out / "gt" / "coco" / f"instance_{v.frame:06d}.json").read_text())
        assert {a["instance_id"] for a in coco["annotations"]} == set(np.unique(m[m >= 0]).tolist())
        for a in coco["annotations"]:
            seg_ = a["segmentation"]
            ours = rle_decode(rle_string_decode(seg_["counts"]), tuple(seg_["size"]))
            assert np.array_equal(ours.astype(bool), m == a["instance_id"])
            if mask_utils is not None:
                rle = dict(seg_, counts=seg_["counts"].encode())
                assert np.array_equal(mask_utils.decode(rle).astype(bool), m == a["instance_id"])
    codes = np.loadtxt(out / "gt" / "scannet_instances.txt", dtype=np.int64)
    assert np.array_equal(np.where(codes > 0, codes % 1000 - 1, -1), inst)
    cat_of = json.loads((out / "gt" / "scannet_categories.json").read_text())
    assert cat_of[str(codes[inst == 0][0] // 1000)] == "mug"
    info = json.loads((out / "gt" / "export_info.json").read_text())
    assert info["log_entries"] == 4
    # never overwritten
    r = subprocess.run([sys.executable, "-m", "clutt3r_core.cli", "export-gt", str(d / "run"), str(out)],
                       capture_output=True, text=True, cwd=REPO)
    assert r.returncode == 2 and "already holds ground truth" in r.stderr


def test_instance_maps_label_only_visible_surface(corrected_run):
    """Against the generator's own per-view ground truth: an exported map agrees with it where
    both label an object (same object up to the id mapping), and a far point behind a near one
    never paints through (the depth is the z-buffer)."""
    from clutt3r_core.io import load_scene

    d, seg, labels = corrected_run
    sc = load_scene(d / "scene")
    v = sc.views[0]
    m = project_labels(seg.points, seg.instance, v.camera, v.depth)
    g = sc.ground_truth.instance_maps[v.frame]
    both = (m >= 0) & (g >= 0)
    assert both.sum() > 100
    # majority mapping predicted id -> GT id explains >= 90 % of the co-labelled pixels
    agree = sum(np.bincount(g[both & (m == k)]).max() for k in np.unique(m[both]))
    assert agree / both.sum() > 0.9
    # z-buffer without depth: two points on one ray, the nearer one wins
    from clutt3r_core.scene import Camera

    cam = Camera(K=np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]]), width=100, height=100,
                 T_world_camera=np.eye(4))
    pts = np.array([[0, 0, 2.0], [0, 0, 1.0], [0, 0, 3.0]])
    out = project_labels(pts, np.array([5, 7, 9]), cam, None, ExportConfig(splat_voxel_m=0.02))
    assert out[50, 50] == 7 and (out == 5).sum() == 0 and (out == 9).sum() == 0


def test_export_without_a_recorded_scene_is_one_clear_error(tmp_path):
    from clutt3r_core.export_gt import export_ground_truth

    with pytest.raises(SceneFileError, match="not a clutt3r run folder"):
        export_ground_truth(tmp_path / "nope", tmp_path / "out")
