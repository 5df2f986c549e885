"""Mask files: the COCO RLE codec, the three import formats, their errors, and the import generator."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from clutt3r_core.errors import SceneFileError
from clutt3r_core.masks import create_mask_generator
from clutt3r_core.masks.formats import (
    read_coco_masks,
    read_npz_masks,
    read_png_masks,
    rle_decode,
    rle_encode,
    rle_string_decode,
    rle_string_encode,
    write_coco_masks,
    write_npz_masks,
    write_png_masks,
)
from clutt3r_core.scene import MaskCandidates
from tests.core.masks._box_scene import box_view

masks_2d = st.integers(1, 24).flatmap(
    lambda h: st.integers(1, 24).flatmap(lambda w: arrays(bool, (h, w)))
)


@settings(max_examples=150, deadline=None)
@given(masks_2d)
def test_rle_round_trip(m):
    counts = rle_encode(m)
    assert sum(counts) == m.size
    assert np.array_equal(rle_decode(counts, m.shape), m)
    assert rle_string_decode(rle_string_encode(counts)) == counts


@settings(max_examples=100, deadline=None)
@given(masks_2d)
def test_rle_string_matches_pycocotools(m):
    mask_api = pytest.importorskip("pycocotools.mask", reason="pycocotools not installed: cross-check skipped")
    ref = mask_api.encode(np.asfortranarray(m.astype(np.uint8)))
    assert rle_string_encode(rle_encode(m)) == ref["counts"].decode()


def _cands(h=20, w=30):
    a = np.zeros((h, w), bool)
    a[2:10, 3:12] = True
    b = np.zeros((h, w), bool)
    b[5:18, 8:25] = True
    c = a & b
    return MaskCandidates(np.stack([a, b, c]), np.array([1, 7, 104], np.int32), np.array([0.9, 0.5, 0.7], np.float32))


def _same(x: MaskCandidates, y: MaskCandidates) -> None:
    ox, oy = np.argsort(x.ids), np.argsort(y.ids)
    assert np.array_equal(x.ids[ox], y.ids[oy])
    assert np.array_equal(x.masks[ox], y.masks[oy])


def test_png_npz_coco_round_trip(tmp_path):
    c = _cands()
    paths = write_png_masks(tmp_path / "png", 3, c)
    assert sorted(p.name for p in paths) == ["mask_000003_01.png", "mask_000003_07.png", "mask_000003_104.png"]
    _same(read_png_masks(tmp_path / "png", 3, (20, 30)), c)
    assert len(read_png_masks(tmp_path / "png", 4, (20, 30))) == 0  # another frame: none
    write_npz_masks(tmp_path / "masks_000003.npz", c)
    got = read_npz_masks(tmp_path / "masks_000003.npz", (20, 30))
    _same(got, c)
    assert np.allclose(got.scores, c.scores)
    write_coco_masks(tmp_path / "m.json", c)
    got = read_coco_masks(tmp_path / "m.json", (20, 30))
    _same(got, c)
    assert np.allclose(got.scores, c.scores)


def test_sample_loader_reads_three_digit_ids(tmp_path):
    """Ids over 99 get three digits; the scene loader's pattern reads them back."""
    from clutt3r_core.io.sample_layout import MASK_NAME

    write_png_masks(tmp_path, 0, _cands())
    assert {int(MASK_NAME.match(p.name).group(2)) for p in tmp_path.iterdir()} == {1, 7, 104}


def test_npz_label_map(tmp_path):
    lab = np.zeros((10, 12), np.int32)
    lab[1:4, 1:4] = 2
    lab[5:9, 6:11] = 5
    np.savez(tmp_path / "v_000000.npz", labels=lab)
    got = read_npz_masks(tmp_path / "v_000000.npz", (10, 12))
    assert got.ids.tolist() == [2, 5] and np.array_equal(got.masks[1], lab == 5)


def test_coco_dataset_dict_selects_view(tmp_path):
    c = _cands()
    recs = json.loads((write_coco_masks(tmp_path / "a.json", c)).read_text())
    d = {"images": [{"id": 11, "file_name": "images/image_000003.png"}, {"id": 12, "file_name": "images/image_000004.png"}],
         "annotations": [{**r, "image_id": 11} for r in recs] + [{**recs[0], "id": 99, "image_id": 12}]}
    (tmp_path / "coco.json").write_text(json.dumps(d))
    got = read_coco_masks(tmp_path / "coco.json", (20, 30), image_name="image_000003.png")
    _same(got, c)
    assert len(read_coco_masks(tmp_path / "coco.json", (20, 30), image_name="image_000004.png")) == 1


def test_coco_polygon_and_uncompressed(tmp_path):
    m = np.zeros((20, 30), bool)
    m[4:9, 5:15] = True
    recs = [{"segmentation": {"size": [20, 30], "counts": rle_encode(m)}},
            {"segmentation": [[5, 4, 14, 4, 14, 8, 5, 8]]}]
    (tmp_path / "p.json").write_text(json.dumps(recs))
    got = read_coco_masks(tmp_path / "p.json", (20, 30))
    assert np.array_equal(got.masks[0], m)
    assert np.array_equal(got.masks[1], m)  # the polygon's corners are pixel centres, filled inclusively


@pytest.mark.parametrize(
    "write, problem",
    [
        (lambda p: write_npz_masks(p / "x.npz", _cands(20, 31)), "31x20 but the view's image is 30x20"),
        (lambda p: np.savez(p / "x.npz", masks=np.zeros((2, 20, 30), bool)), "empty masks"),
        (lambda p: np.savez(p / "x.npz", masks=np.ones((1, 20, 30), bool), ids=np.array([-3])), "out of range"),
        (lambda p: np.savez(p / "x.npz", masks=np.ones((2, 20, 30), bool), ids=np.array([4, 4])), "duplicate"),
        (lambda p: np.savez(p / "x.npz", stuff=np.ones(3)), "needs an array 'masks'"),
        (lambda p: (p / "x.npz").write_bytes(b"not a zip"), "not a readable npz"),
    ],
)
def test_npz_errors_name_the_file(tmp_path, write, problem):
    write(tmp_path)
    with pytest.raises(SceneFileError, match=problem) as e:
        read_npz_masks(tmp_path / "x.npz", (20, 30))
    assert e.value.path == tmp_path / "x.npz"


@pytest.mark.parametrize(
    "seg, problem",
    [
        ({"size": [20, 31], "counts": "0"}, "31x20 but the view's image is 30x20"),
        ({"size": [20, 30], "counts": [10, 5]}, "bad RLE"),
        ({"size": [20, 30], "counts": [600]}, "empty masks"),
        ({"size": [20, 30], "counts": "\x7f\x7f"}, "bad RLE"),
        ("nonsense", "must be an RLE dict or a polygon"),
    ],
)
def test_coco_errors_name_the_file(tmp_path, seg, problem):
    (tmp_path / "m.json").write_text(json.dumps([{"segmentation": seg}]))
    with pytest.raises(SceneFileError, match=problem) as e:
        read_coco_masks(tmp_path / "m.json", (20, 30))
    assert e.value.path == tmp_path / "m.json"


def test_png_errors(tmp_path):
    from clutt3r_core.io.images import write_png

    write_png(tmp_path / "mask_000000_01.png", np.zeros((20, 30), bool))
    with pytest.raises(SceneFileError, match="empty mask") as e:
        read_png_masks(tmp_path, 0, (20, 30))
    assert e.value.path.name == "mask_000000_01.png"
    write_png(tmp_path / "mask_000000_01.png", np.ones((21, 30), bool))
    with pytest.raises(SceneFileError, match="mask_000000_01.png"):
        read_png_masks(tmp_path, 0, (20, 30))


@pytest.mark.parametrize("fmt", ["png", "npz", "coco"])
def test_import_generator(tmp_path, fmt):
    view, ids = box_view(width=64, height=48, f=60.0, frame=5)
    c = MaskCandidates(np.stack([ids == 0, ids >= 0]), np.array([1, 2], np.int32))
    if fmt == "png":
        write_png_masks(tmp_path, 5, c)
    elif fmt == "npz":
        write_npz_masks(tmp_path / "masks_000005.npz", c)
    else:
        write_coco_masks(tmp_path / "image_000005.json", c)
    gen = create_mask_generator("import", source=tmp_path)
    assert gen.format == fmt
    _same(gen.generate(view), c)


def test_import_generator_errors(tmp_path):
    with pytest.raises(SceneFileError, match="no mask files"):
        create_mask_generator("import", source=tmp_path)
    with pytest.raises(SceneFileError, match="needs a source"):
        create_mask_generator("import")
    view, _ = box_view(width=64, height=48, f=60.0, frame=2)
    write_npz_masks(tmp_path / "masks_000005.npz", _cands())
    with pytest.raises(SceneFileError, match="no .npz mask file for frame 2"):
        create_mask_generator("import", source=tmp_path).generate(view)
