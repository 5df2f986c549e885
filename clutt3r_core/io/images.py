"""Image file reading and writing with errors that name the file.

OpenCV reads and writes PNGs here (fast, releases the GIL so views load in parallel
threads). Every failure becomes a SceneFileError naming the path and the problem.

A PNG's chunk structure and CRCs are checked before OpenCV decodes it: a truncated or
bit-flipped file is then named precisely ("ends inside its IDAT chunk") and libpng never
gets to print its own "libpng error: ..." line on the user's terminal (it writes to
stderr whatever OpenCV's log level is). Costs one CRC-32 pass over the bytes (about
1 ms per MB).
"""

from __future__ import annotations

import functools
import os
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import Iterable, Iterator

# OpenCV reads its log level once, at import: keep its warnings off the terminal unless
# the user asked for them (every image failure becomes a SceneFileError here anyway)
os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from clutt3r_core.errors import SceneFileError

try:
    # zlib-ng's inflate and CRC-32: the same bytes and values as zlib's, faster (issue 13,
    # sample_seq4's 120 1080p masks, mostly long zero runs: inflate 0.31 -> 0.07 s of CPU;
    # the CRC of its 11 MB of colour PNGs 3.3 -> 0.7 ms). zlib when it is not installed.
    from zlib_ng import zlib_ng as _zlib
except ImportError:  # pragma: no cover - a core dependency (pyproject.toml)
    _zlib = zlib
_ZLIB_ERRORS = (zlib.error, _zlib.error)

__all__ = [
    "read_rgb", "read_depth_mm", "read_mask", "read_masks", "read_label_png", "io_threads", "release_freed_memory",
    "write_png", "atomic_write_bytes", "npz_bytes",
    "atomic_write_npz", "NPZ_READ_ERRORS",
]

NPZ_READ_ERRORS: tuple[type[BaseException], ...] = (
    OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error,
    NotImplementedError,  # zipfile: an unknown zip version or compression method (a flipped header byte)
    RuntimeError,  # zipfile: a member flagged as encrypted
)
"""What ``np.load`` of a damaged .npz can raise (found by fuzzing, tests/core/robustness); every
reader of an npz file turns these into a SceneFileError naming the file."""


def io_threads() -> int:
    """Threads for reading or writing a scene's images: one per usable CPU, at most 8.

    The decoders are CPU-bound (OpenCV and zlib release the GIL), so threads beyond the cores
    load no faster, and each thread keeps its own malloc arena, with its high-water mark of
    decoded-image temporaries, for the rest of the process (issue 13, measured on the shared
    2-core machine: sample_seq4's whole-command peak RSS 530 MiB with 8 loader threads, 481
    with 4, 390 with 2; loading took the same CPU).
    """
    try:
        n = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):  # not Linux
        n = os.cpu_count() or 1
    return max(1, min(8, n))


def release_freed_memory() -> None:
    """Return the C heap's free pages to the system (glibc's ``malloc_trim``; nothing elsewhere).

    The loaders call it once their decoding threads are done: each such thread allocated its
    decoded-image temporaries in its own malloc arena, which keeps the freed pages resident for
    the rest of the process, under everything the segmentation allocates next (issue 13,
    sample_seq4's whole-command peak: median 523 -> 494 MiB over 7 alternating runs; the call
    takes ~1 ms).
    """
    trim = _malloc_trim()
    if trim:
        trim(0)


@functools.cache
def _malloc_trim():
    """glibc's ``malloc_trim``, or False where the process has none (looked up once)."""
    import ctypes

    try:  # the process's own symbols, the C library's among them (ctypes.util.find_library runs ldconfig)
        return getattr(ctypes.CDLL(None), "malloc_trim", False)
    except OSError:  # pragma: no cover - a platform without dlopen(NULL)
        return False


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JPEG_SOI, _JPEG_EOI = b"\xff\xd8", b"\xff\xd9"


def _check_png(path: Path, buf: memoryview) -> None:
    """Raise SceneFileError unless ``buf`` is a structurally whole PNG: IHDR first, every chunk
    complete with a matching CRC-32, IEND present (PNG spec, sec. 5.3)."""
    n, pos, first = len(buf), 8, True
    while True:
        if pos + 8 > n:
            raise SceneFileError(path, "corrupt or truncated PNG: it ends before its IEND chunk (file cut short?)")
        length = int.from_bytes(buf[pos : pos + 4], "big")
        ctype = bytes(buf[pos + 4 : pos + 8])
        name = ctype.decode("latin-1") if ctype.isalpha() else repr(ctype)
        if first and ctype != b"IHDR":
            raise SceneFileError(path, f"corrupt PNG: the first chunk is {name}, not IHDR")
        if length > 0x7FFFFFFF or not ctype.isalpha():
            raise SceneFileError(path, f"corrupt PNG: bad chunk header at byte {pos}")
        end = pos + 12 + length
        if end > n:
            raise SceneFileError(path, f"corrupt or truncated PNG: the file ends inside its {name} chunk (file cut short?)")
        crc = int.from_bytes(buf[end - 4 : end], "big")
        if _zlib.crc32(buf[pos + 4 : end - 4]) != crc:
            raise SceneFileError(path, f"corrupt or truncated PNG: chunk {name} at byte {pos} fails its CRC check")
        if ctype == b"IEND":
            return
        pos, first = end, False


def _imread(path: Path, flags: int) -> np.ndarray:
    return _decode(path, _read_checked(path), flags)


def _read_checked(path: Path) -> np.ndarray:
    """The bytes of an image file, its structure checked (PNG chunks and CRCs, JPEG end marker)."""
    if not path.is_file():
        raise SceneFileError(path, "file not found")
    try:
        data = np.fromfile(path, dtype=np.uint8)
    except OSError as e:
        raise SceneFileError(path, f"cannot be read ({e.strerror or e})") from None
    if data.size == 0:
        raise SceneFileError(path, "file is empty")
    buf = memoryview(data)
    if bytes(buf[:8]) == _PNG_SIGNATURE:
        _check_png(path, buf)
    elif bytes(buf[:2]) == _JPEG_SOI and bytes(buf[-64:]).rfind(_JPEG_EOI) < 0:
        # libjpeg would decode the part it has, grey below, and warn on stderr
        raise SceneFileError(path, "truncated JPEG: no end-of-image marker (file cut short?)")
    return data


def _decode(path: Path, data: np.ndarray, flags: int) -> np.ndarray:
    try:
        img = cv2.imdecode(data, flags)
    except cv2.error as e:  # e.g. a header claiming more pixels than OpenCV's limit
        msg = str(e).strip().splitlines()[-1] if str(e).strip() else "decoder error"
        raise SceneFileError(path, f"not a readable image ({msg})") from None
    if img is None:
        raise SceneFileError(path, "not a readable image (corrupt or truncated PNG?)")
    return img


_RUN_LOOP_MAX = 20000
"""More runs than this per mask are painted by a cumulative sum instead of one slice each."""


def _sub_png_mask(data: np.ndarray) -> np.ndarray | None:
    """(H, W) bool ``pixel != 0`` of a checked 8-bit greyscale, non-interlaced PNG whose rows are
    all Sub-filtered (or None-filtered and all zero); None for any other PNG (or a zlib stream
    that does not inflate to the image), which the caller decodes with OpenCV.

    Sub filtering stores each byte minus its left neighbour (PNG spec, sec. 9.2), so a mask's
    filtered rows are zero except where the value changes: the inflated rows are scanned 8
    bytes at a time for those changes, the value after each is the running sum (mod 256) of
    the row's changes, and the runs of non-zero value are painted. No row is unfiltered
    pixel by pixel.

    Why by hand and not a library: a decoder must unfilter every byte; this one skips the zero
    bytes. sample_seq4's 120 1080p masks: OpenCV (libpng) 1.34 s CPU, pyspng (libspng) 1.32 s,
    this path 0.53 s (2026-11-30). Any PNG it does not recognise still goes to OpenCV.
    """
    b = data.tobytes()
    pos, n, hdr, idat = 8, len(b), None, []
    while pos + 8 <= n:  # the structure was checked by _check_png: IHDR first, IEND last
        length = int.from_bytes(b[pos : pos + 4], "big")
        ctype = b[pos + 4 : pos + 8]
        if ctype == b"IHDR":
            hdr = b[pos + 8 : pos + 8 + length]
        elif ctype == b"IDAT":
            idat.append(b[pos + 8 : pos + 8 + length])
        elif ctype == b"IEND":
            break
        pos += 12 + length
    if hdr is None or len(hdr) != 13:
        return None
    w, h = int.from_bytes(hdr[0:4], "big"), int.from_bytes(hdr[4:8], "big")
    if hdr[8:13] != bytes([8, 0, 0, 0, 0]) or not 0 < w * h <= 1 << 28:  # 8-bit grey, deflate, no interlace
        return None
    stride = w + 1  # a filter-type byte, then the row
    try:  # at most one byte more than the image needs: a stream that inflates further is not ours
        raw = _zlib.decompressobj().decompress(b"".join(idat), h * stride + 1)
    except _ZLIB_ERRORS:
        return None
    if len(raw) != h * stride:
        return None
    flat = np.frombuffer(raw, np.uint8)
    ftype = flat[::stride]
    if np.any((ftype != 1) & (ftype != 0)):
        return None  # another filter (libpng's adaptive choice): OpenCV decodes it
    # non-zero bytes: words first (the filtered rows are almost all zero), then their bytes
    nw = len(raw) // 8
    words = np.flatnonzero(np.frombuffer(raw, np.uint64, count=nw))
    cand = (words[:, None] * 8 + np.arange(8)).reshape(-1)
    cand = np.concatenate([cand, np.arange(nw * 8, len(raw))])
    nz = cand[flat[cand] != 0]
    row, col = np.divmod(nz, stride)
    change = col > 0
    if np.any(ftype[row[change]] != 1):
        return None  # a None-filtered row with data: OpenCV decodes it
    t, trow, tcol = nz[change], row[change], col[change] - 1
    mask = np.zeros(h * w, bool)
    if not len(t):
        return mask.reshape(h, w)
    vals = flat[t].astype(np.int64)
    first = np.flatnonzero(np.r_[True, trow[1:] != trow[:-1]])  # each row's first change
    cs = np.cumsum(vals)
    before = cs[first] - vals[first]
    value = (cs - np.repeat(before, np.diff(np.r_[first, len(t)]))) % 256
    end = np.r_[tcol[1:], w]
    end[np.flatnonzero(trow[1:] != trow[:-1])] = w  # a row's last change runs to the row's end
    on = value != 0
    starts, stops = trow[on] * w + tcol[on], trow[on] * w + end[on]
    if len(starts) <= _RUN_LOOP_MAX:
        for a, z in zip(starts.tolist(), stops.tolist()):
            mask[a:z] = True
    else:
        d = np.zeros(h * w + 1, np.int32)
        np.add.at(d, starts, 1)
        np.add.at(d, stops, -1)
        mask = np.cumsum(d[:-1]) > 0
    return mask.reshape(h, w)


def read_rgb(path: str | Path, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Read an 8-bit colour image as (H, W, 3) uint8 RGB."""
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        raise SceneFileError(path, f"colour image must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = cv2.cvtColor(img, cv2.COLOR_BGRA2RGB)
    else:
        img = cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
    _check_hw(path, img, expect_hw, "image")
    return img


def read_depth_mm(path: str | Path, expect_hw: tuple[int, int] | None = None, scale: float = 0.001) -> np.ndarray:
    """Read a 16-bit depth PNG and return (H, W) float32 metres, NaN for holes (value 0).

    ``scale`` converts file units to metres (0.001 for millimetres).
    """
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint16:
        raise SceneFileError(path, f"depth PNG must be 16-bit (uint16 millimetres), got {img.dtype}")
    if img.ndim != 2:
        raise SceneFileError(path, f"depth PNG must be single-channel, got {img.shape[2]} channels")
    _check_hw(path, img, expect_hw, "depth")
    d = img.astype(np.float32)
    d *= np.float32(scale)  # in place: one (H, W) float32 per depth map, not two
    d[img == 0] = np.nan
    return d


def read_masks(paths: Iterable[str | Path], expect_hw: tuple[int, int] | None = None) -> Iterator[np.ndarray]:
    """``read_mask`` of each path, one at a time (a generator: ``MaskCandidates.from_masks``
    encodes each before the next is read). After the first mask that is not a Sub-filtered
    PNG, the rest go straight to OpenCV (one tool wrote the folder: trying each would inflate
    each twice)."""
    fast = True
    for p in paths:
        m, fast = _read_mask(Path(p), expect_hw, fast)
        yield m


def read_mask(path: str | Path, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Read a binary mask PNG (0 / 255, or any non-zero) as (H, W) bool.

    8-bit greyscale PNGs whose rows are Sub-filtered (what OpenCV and so this tool write, and
    every mask of the real samples) are decoded here from their few value changes per row
    (``_sub_png_mask``), not by libpng: a 1080p mask of a few kB took 9 ms to decode into a
    2 MB image and 1 ms more to threshold; this takes a fraction of that (issue 13, 1080p
    whole-command time). Any other PNG goes to OpenCV. The result is the same either way.
    """
    return _read_mask(Path(path), expect_hw, True)[0]


def _read_mask(path: Path, expect_hw: tuple[int, int] | None, fast: bool) -> tuple[np.ndarray, bool]:
    """(``read_mask``, whether ``_sub_png_mask`` decoded it): that path is tried when ``fast``,
    OpenCV decodes the file otherwise and when it is not such a PNG (the file is read and
    checked once either way)."""
    data = _read_checked(path)
    m = _sub_png_mask(data) if fast and bytes(data[:8]) == _PNG_SIGNATURE else None
    if m is not None:
        _check_hw(path, m, expect_hw, "mask")
        return m, True
    img = _decode(path, data, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        img = img[:, :, :3].max(axis=2)
    _check_hw(path, img, expect_hw, "mask")
    return img > 0, False


def read_label_png(path: str | Path, expect_hw: tuple[int, int] | None = None) -> np.ndarray:
    """Read a single-channel 8- or 16-bit label PNG as (H, W) int32."""
    path = Path(path)
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim != 2:
        raise SceneFileError(path, f"label PNG must be single-channel, got shape {img.shape}")
    _check_hw(path, img, expect_hw, "label image")
    return img.astype(np.int32)


def _check_hw(path: Path, img: np.ndarray, expect_hw: tuple[int, int] | None, what: str) -> None:
    if expect_hw is not None and tuple(img.shape[:2]) != tuple(expect_hw):
        h, w = expect_hw
        raise SceneFileError(path, f"{what} is {img.shape[1]}x{img.shape[0]} but {w}x{h} was expected")


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically: temp file in the same folder, fsync, rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


# zlib level of the .npz files the tool writes (ours, issue 13): level 1 took half the CPU of
# np.savez_compressed's default level 6 on a 1080p run folder (0.21 vs 0.39 s) for files 2 %
# larger; a run is written once per command and read back by np.load either way.
NPZ_COMPRESSLEVEL = 1


def npz_bytes(*, stored: Iterable[str] = (), **arrays: np.ndarray) -> bytes:
    """``arrays`` as the bytes of a compressed ``.npz`` without touching disk: the layout of
    ``np.savez_compressed`` (one deflated ``NAME.npy`` member per array), at zlib level
    ``NPZ_COMPRESSLEVEL``. The arrays named in ``stored`` are members without compression
    (np.load reads either): float coordinates deflate by only 13-15 % for most of the CPU."""
    import io
    import time

    from numpy.lib import format as npy_format

    stored = set(stored)
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED, compresslevel=NPZ_COMPRESSLEVEL) as zf:
        for name, value in arrays.items():
            member: str | zipfile.ZipInfo = name + ".npy"
            if name in stored:
                member = zipfile.ZipInfo(name + ".npy", date_time=time.localtime(time.time())[:6])
                member.compress_type = zipfile.ZIP_STORED
            with zf.open(member, "w", force_zip64=True) as f:
                npy_format.write_array(f, np.asanyarray(value), allow_pickle=True)
    return buf.getvalue()


def atomic_write_npz(path: str | Path, *, stored: Iterable[str] = (), **arrays: np.ndarray) -> None:
    """Write ``arrays`` as a compressed ``.npz`` atomically (every compressed npz the tool saves goes
    through here; the query cache and the annotation log write theirs uncompressed with np.savez);
    ``stored``: as in ``npz_bytes``."""
    atomic_write_bytes(path, npz_bytes(stored=stored, **arrays))


def write_png(path: str | Path, img: np.ndarray, *, sub_filter: bool = False) -> None:
    """Write uint8 RGB (H, W, 3), uint8 (H, W), bool (H, W) as 0/255, or uint16 (H, W) as PNG.

    ``sub_filter``: every row Sub-filtered instead of libpng's per-row adaptive choice: the
    same pixels in about half the encoding CPU for a picture (ours, issue 13: the segment
    command's 1920x360 overview.png 79 -> 37 ms, the file 2 % smaller).
    """
    img = np.asarray(img)
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.ndim == 3:
        if img.dtype != np.uint8 or img.shape[2] != 3:
            raise ValueError(f"colour PNG must be (H, W, 3) uint8, got {img.dtype} {img.shape}")
        img = cv2.cvtColor(img, cv2.COLOR_RGB2BGR)
    elif img.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"single-channel PNG must be uint8 or uint16, got {img.dtype}")
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1]
    if sub_filter:
        params += [cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    ok, buf = cv2.imencode(".png", img, params)
    if not ok:
        raise SceneFileError(path, "PNG encoding failed")
    atomic_write_bytes(path, buf.tobytes())
