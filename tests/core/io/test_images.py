"""``io.images.read_mask``'s own decoder of Sub-filtered PNGs gives what OpenCV gives (issue 13)."""

from __future__ import annotations

import zlib

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneFileError
from clutt3r_core.io import images
from clutt3r_core.io.images import _sub_png_mask, read_mask, read_masks


def _png(img: np.ndarray, filt: int | None) -> bytes:
    """PNG bytes of a uint8 (H, W) image; ``filt`` = OpenCV's PNG filter flag (None: its default)."""
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1] + ([] if filt is None else [cv2.IMWRITE_PNG_FILTER, filt])
    ok, buf = cv2.imencode(".png", img, params)
    assert ok
    return buf.tobytes()


def _filters(png: bytes, h: int, w: int) -> np.ndarray:
    """The filter-type byte of every row of an 8-bit greyscale PNG."""
    i = png.index(b"IDAT")
    raw = zlib.decompress(png[i + 4 : i + 4 + int.from_bytes(png[i - 4 : i], "big")])
    return np.frombuffer(raw, np.uint8)[:: w + 1][:h]


def _image(seed: int, h: int, w: int, kind: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    img = np.zeros((h, w), np.uint8)
    if kind == 0:  # a binary mask of boxes
        for _ in range(rng.integers(0, 4)):
            y, x = rng.integers(0, h), rng.integers(0, w)
            img[y : y + rng.integers(1, h + 1), x : x + rng.integers(1, w + 1)] = 255
    elif kind == 1:  # binary noise: many runs
        img[rng.random((h, w)) < rng.random()] = 255
    else:  # any byte values (a "mask" is every non-zero pixel)
        img = rng.integers(0, 256, (h, w), dtype=np.uint8) * (rng.random((h, w)) < 0.5)
    return img.astype(np.uint8)


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), h=st.integers(1, 40), w=st.integers(1, 40), kind=st.integers(0, 2))
def test_sub_filtered_masks_decode_like_opencv(tmp_path_factory, seed, h, w, kind):
    """Property: for Sub-filtered PNGs the fast path is taken and equals OpenCV's pixels != 0;
    for OpenCV's default (adaptive) filters read_mask still equals it (through OpenCV).
    (libpng may still pick None for a row, e.g. in a one-pixel-wide image.)"""
    img = _image(seed, h, w, kind)
    folder = tmp_path_factory.mktemp("m")
    for name, filt in (("sub.png", cv2.IMWRITE_PNG_FILTER_SUB), ("any.png", None), ("none.png", cv2.IMWRITE_PNG_FILTER_NONE)):
        p = folder / name
        png = _png(img, filt)
        p.write_bytes(png)
        fast = _sub_png_mask(np.fromfile(p, np.uint8))
        if (_filters(png, h, w) == 1).all():
            assert fast is not None
        if fast is not None:
            np.testing.assert_array_equal(fast, img != 0)
        np.testing.assert_array_equal(read_mask(p, (h, w)), img != 0)


def test_many_runs_are_painted_by_a_cumulative_sum(tmp_path, monkeypatch):
    img = _image(3, 30, 50, 1)
    p = tmp_path / "m.png"
    p.write_bytes(_png(img, cv2.IMWRITE_PNG_FILTER_SUB))
    monkeypatch.setattr(images, "_RUN_LOOP_MAX", 3)
    np.testing.assert_array_equal(read_mask(p), img != 0)


def test_read_masks_falls_back_once_and_checks_sizes(tmp_path):
    a, b = _image(1, 20, 30, 0), _image(2, 20, 30, 1)
    (tmp_path / "a.png").write_bytes(_png(a, cv2.IMWRITE_PNG_FILTER_PAETH))  # not Sub: OpenCV
    (tmp_path / "b.png").write_bytes(_png(b, cv2.IMWRITE_PNG_FILTER_SUB))
    got = list(read_masks([tmp_path / "a.png", tmp_path / "b.png"], (20, 30)))
    np.testing.assert_array_equal(got[0], a != 0)
    np.testing.assert_array_equal(got[1], b != 0)
    with pytest.raises(SceneFileError, match="30x20 but 31x20"):
        read_mask(tmp_path / "b.png", (20, 31))


@pytest.fixture(params=["zlib-ng", "zlib"])
def inflater(request, monkeypatch):
    """The module's inflater: zlib-ng (a core dependency, faster) and stdlib zlib (its fallback)."""
    if request.param == "zlib":
        monkeypatch.setattr(images, "_zlib", zlib)
    else:
        assert images._zlib is not zlib, "zlib_ng is a core dependency and should be installed"
    return request.param


def test_both_inflaters_decode_the_same_masks(tmp_path, inflater):
    """zlib-ng and zlib give the same mask of every kind of image (the same inflated bytes)."""
    for seed, (h, w), kind in ((0, (37, 53), 0), (1, (64, 9), 1), (2, (21, 40), 2), (3, (30, 200), 0)):
        img = _image(seed, h, w, kind)
        p = tmp_path / f"m{seed}.png"
        p.write_bytes(_png(img, cv2.IMWRITE_PNG_FILTER_SUB))
        fast = _sub_png_mask(np.fromfile(p, np.uint8))
        assert fast is not None
        np.testing.assert_array_equal(fast, img != 0)


def test_a_corrupt_deflate_stream_is_named(tmp_path, inflater):
    """Chunk CRCs intact but the zlib stream broken: OpenCV's path reports the file (either
    inflater's error is caught: zlib_ng.error is not a zlib.error)."""
    img = _image(4, 16, 16, 0)
    raw = bytearray(_png(img, cv2.IMWRITE_PNG_FILTER_SUB))
    i = raw.index(b"IDAT")
    n = int.from_bytes(raw[i - 4 : i], "big")
    raw[i + 4 : i + 4 + n] = b"\x00" * n
    raw[i + 4 + n : i + 8 + n] = zlib.crc32(bytes(raw[i : i + 4 + n])).to_bytes(4, "big")
    p = tmp_path / "bad.png"
    p.write_bytes(bytes(raw))
    assert _sub_png_mask(np.fromfile(p, np.uint8)) is None
    with pytest.raises(SceneFileError, match="bad.png"):
        read_mask(p)


def test_io_threads_follow_the_usable_cpus(monkeypatch):
    monkeypatch.setattr(images.os, "sched_getaffinity", lambda pid: set(range(3)), raising=False)
    assert images.io_threads() == 3
    monkeypatch.setattr(images.os, "sched_getaffinity", lambda pid: set(range(64)), raising=False)
    assert images.io_threads() == 8
    monkeypatch.delattr(images.os, "sched_getaffinity", raising=False)
    monkeypatch.setattr(images.os, "cpu_count", lambda: None)
    assert images.io_threads() == 1


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), flips=st.integers(1, 4))
def test_a_damaged_sub_png_reads_as_opencv_reads_it_or_is_refused(tmp_path_factory, seed, flips):
    """Property: bytes of the deflate stream flipped and the chunk CRC made valid again: the
    fast path and OpenCV agree (the same pixels), or read_mask raises a SceneFileError."""
    rng = np.random.default_rng(seed)
    img = _image(seed, 24, 33, 0)
    raw = bytearray(_png(img, cv2.IMWRITE_PNG_FILTER_SUB))
    i = raw.index(b"IDAT")
    n = int.from_bytes(raw[i - 4 : i], "big")
    for k in rng.integers(0, n, flips):
        raw[i + 4 + k] ^= int(rng.integers(1, 256))
    raw[i + 4 + n : i + 8 + n] = zlib.crc32(bytes(raw[i : i + 4 + n])).to_bytes(4, "big")
    p = tmp_path_factory.mktemp("d") / "m.png"
    p.write_bytes(bytes(raw))
    ref = cv2.imdecode(np.frombuffer(bytes(raw), np.uint8), cv2.IMREAD_UNCHANGED)
    if ref is None:
        with pytest.raises(SceneFileError, match="m.png"):
            read_mask(p)
    else:
        np.testing.assert_array_equal(read_mask(p), (ref > 0) if ref.ndim == 2 else ref[:, :, :3].max(axis=2) > 0)


@pytest.mark.parametrize("shape", [(30, 40, 3), (17, 9), (1, 1, 3)])
def test_sub_filtered_png_holds_the_same_pixels(tmp_path, shape):
    img = np.random.default_rng(0).integers(0, 256, shape, dtype=np.uint8)
    images.write_png(tmp_path / "a.png", img)
    images.write_png(tmp_path / "b.png", img, sub_filter=True)
    a, b = cv2.imread(str(tmp_path / "a.png"), cv2.IMREAD_UNCHANGED), cv2.imread(str(tmp_path / "b.png"), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(a, b)
    raw = (tmp_path / "b.png").read_bytes()
    if len(shape) == 2:  # greyscale: every row's filter byte is Sub (1)
        assert (_filters(raw, *shape) == 1).all()


def test_release_freed_memory_returns_a_threads_freed_pages():
    """glibc's malloc_trim after the loaders' decoding threads (issue 13, 1080p peak): a thread's
    arena keeps the pages of what it freed below a block still in use; the call returns them."""
    import subprocess
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("malloc_trim is glibc's; elsewhere the call does nothing")
    prog = (
        "import os, threading\n"
        "from clutt3r_core.io import images\n"
        "rss = lambda: int(open('/proc/self/statm').read().split()[1]) * os.sysconf('SC_PAGE_SIZE') / 2**20\n"
        "keep = []\n"
        "def work():\n"
        "    xs = [bytearray(60000) for _ in range(2000)]  # ~115 MiB below the mmap threshold\n"
        "    keep.append(xs[-1])  # the arena's top stays in use: free() alone cannot shrink it\n"
        "t = threading.Thread(target=work); t.start(); t.join()\n"
        "a = rss(); images.release_freed_memory(); images.release_freed_memory(); print(a, rss())\n"
    )
    r = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, timeout=120)
    before, after = map(float, r.stdout.split())
    assert before - after > 80, (before, after)
