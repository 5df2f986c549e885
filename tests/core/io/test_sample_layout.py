from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.io.sample_layout import load_sample_layout, write_sample_layout


@pytest.mark.realdata
def test_seq1_loads_with_post_frames_without_depth(seq1_dir):
    scene = load_sample_layout(seq1_dir)
    assert len(scene.views) == 10
    assert [scene.views[i].frame for i in scene.initial] == list(range(8))
    assert [scene.views[i].frame for i in scene.post] == [8, 9]
    for v in scene.post_views:
        assert v.depth is None
        assert v.rgb.shape == (480, 640, 3)
    for v in scene.initial_views:
        assert v.depth is not None and v.depth.dtype == np.float32
        # real depth of a tabletop capture: metres, well inside 0.1..2 m where valid
        d = v.depth[np.isfinite(v.depth)]
        assert 0.1 < np.median(d) < 2.0
        assert v.masks is not None and len(v.masks) >= 10
    assert scene.views[4].masks.ids.tolist() == list(range(1, 15))


@pytest.mark.realdata
def test_seq4_loads_full_hd(seq4_dir):
    scene = load_sample_layout(seq4_dir)
    assert len(scene.initial) == 8 and scene.post == ()
    v = scene.views[0]
    assert v.rgb.shape == (1080, 1920, 3) and v.depth.shape == (1080, 1920)
    assert v.camera.K[0, 0] == pytest.approx(1403.8768, rel=1e-6)


@pytest.mark.realdata
def test_seq1_roundtrip_is_lossless(seq1_dir, tmp_path):
    a = load_sample_layout(seq1_dir)
    write_sample_layout(a, tmp_path / "copy")
    b = load_sample_layout(tmp_path / "copy")
    assert a.initial == b.initial and a.post == b.post
    for va, vb in zip(a.views, b.views):
        assert va.frame == vb.frame
        np.testing.assert_array_equal(va.rgb, vb.rgb)
        np.testing.assert_array_equal(va.camera.K, vb.camera.K)
        np.testing.assert_allclose(va.camera.T_world_camera, vb.camera.T_world_camera, atol=0, rtol=0)
        if va.depth is None:
            assert vb.depth is None
        else:
            np.testing.assert_array_equal(np.isnan(va.depth), np.isnan(vb.depth))
            np.testing.assert_array_equal(np.nan_to_num(va.depth), np.nan_to_num(vb.depth))
        np.testing.assert_array_equal(va.masks.ids, vb.masks.ids)
        np.testing.assert_array_equal(va.masks.masks, vb.masks.masks)


def test_npz_bytes_reads_back_as_savez_compressed_would():
    """Issue 13: the tool's .npz files are written at zlib level 1 (half the CPU of numpy's
    default level); np.load must read the same arrays, dtypes and shapes, scalars and empty
    arrays included, from members that are deflated."""
    import io
    import zipfile

    from clutt3r_core.io.images import npz_bytes

    rng = np.random.default_rng(0)
    arrays = {
        "points": rng.random((1000, 3)).astype(np.float32),
        "labels": rng.integers(-1, 9, 1000).astype(np.int32),
        "flags": rng.random(37) < 0.5,
        "scalar": np.int32(7),
        "empty": np.zeros((0, 4), np.float64),
        "text": np.array("a phrase"),
    }
    data = npz_bytes(**arrays)
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        assert sorted(zf.namelist()) == sorted(k + ".npy" for k in arrays)
        assert all(i.compress_type == zipfile.ZIP_DEFLATED for i in zf.infolist())
    with np.load(io.BytesIO(data)) as z:
        for k, v in arrays.items():
            got = z[k]
            assert got.dtype == np.asarray(v).dtype and got.shape == np.shape(v)
            np.testing.assert_array_equal(got, v)
    # members named in ``stored`` are written without compression and read back the same
    data = npz_bytes(stored=("points", "empty"), **arrays)
    with zipfile.ZipFile(io.BytesIO(data)) as zf:
        kinds = {i.filename: i.compress_type for i in zf.infolist()}
    assert kinds == {k + ".npy": zipfile.ZIP_STORED if k in ("points", "empty") else zipfile.ZIP_DEFLATED
                     for k in arrays}
    with np.load(io.BytesIO(data)) as z:
        for k, v in arrays.items():
            got = z[k]
            assert got.dtype == np.asarray(v).dtype and got.shape == np.shape(v)
            np.testing.assert_array_equal(got, v)
