"""Mask candidates on disk, in the formats people hold, read and written per view.

Three formats (each error names the file and the problem):

* **PNG folder** (the sample layout's ``instance_masks/``): one 0/255 PNG per candidate,
  ``mask_{frame:06d}_{id:02d}.png``. Ids of 100 and more simply get more digits
  (``mask_000003_104.png``); the loader's pattern ``mask_(\\d+)_(\\d+).png`` reads them.
* **stacked npz**, one file per view (``masks_{frame:06d}.npz`` or any name with the frame
  number as its last number): either ``masks`` (M, H, W) bool/uint8 with optional ``ids``
  (M,) and ``scores`` (M,), or ``labels`` (H, W) int, 0 = no mask, k > 0 = candidate k
  (a label map cannot overlap, so it gives no hierarchy).
* **COCO RLE JSON**, what SAM's ``SamAutomaticMaskGenerator(output_mode="coco_rle")`` and
  Grounded-SAM scripts write: a list of records with ``segmentation`` =
  ``{"size": [h, w], "counts": str | list[int]}`` (compressed or uncompressed RLE, column-major
  as COCO defines it) or a polygon list, optional ``score`` / ``predicted_iou`` and ``id``;
  or a COCO dict with ``images`` and ``annotations`` (one file for many views, matched by
  ``image_id`` = frame or by the image's ``file_name``).

RLE is implemented with numpy here (``rle_encode`` / ``rle_decode``), bit-compatible with
pycocotools (a test compares them when pycocotools is installed), so no compiled COCO
package is needed.
"""

from __future__ import annotations

import json
import re
import zipfile
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneFileError
from clutt3r_core.scene import MaskCandidates

__all__ = [
    "rle_encode",
    "rle_decode",
    "rle_string_encode",
    "rle_string_decode",
    "read_png_masks",
    "read_npz_masks",
    "read_coco_masks",
    "write_png_masks",
    "write_npz_masks",
    "write_coco_masks",
    "mask_png_name",
    "MAX_MASK_ID",
]

MAX_MASK_ID = 999_999
"""Largest candidate id we accept (file names stay short; a view never has that many masks)."""

_MASK_NAME = re.compile(r"^mask_(\d+)_(\d+)\.png$")
_LAST_NUMBER = re.compile(r"(\d+)(?!.*\d)")


def mask_png_name(frame: int, mask_id: int) -> str:
    """Sample-layout file name of one candidate (``mask_{frame:06d}_{id:02d}.png``)."""
    return f"mask_{int(frame):06d}_{int(mask_id):02d}.png"


# -- COCO run-length encoding ----------------------------------------------------------------


def rle_encode(mask: np.ndarray) -> list[int]:
    """Uncompressed COCO RLE of a (H, W) bool mask: run lengths in column-major (Fortran)
    order, starting with a run of zeros (possibly of length 0)."""
    flat = np.asarray(mask, dtype=bool).ravel(order="F")
    if flat.size == 0:
        return []
    change = np.flatnonzero(flat[1:] != flat[:-1]) + 1
    bounds = np.concatenate([[0], change, [flat.size]])
    runs = np.diff(bounds).tolist()
    if flat[0]:
        runs = [0] + runs
    return runs


def rle_decode(counts: list[int] | np.ndarray, hw: tuple[int, int]) -> np.ndarray:
    """(H, W) bool mask from uncompressed COCO RLE counts. Raises ValueError if the runs do
    not add up to H * W."""
    h, w = int(hw[0]), int(hw[1])
    runs = np.asarray(counts, dtype=np.int64).reshape(-1)
    if (runs < 0).any():
        raise ValueError("negative run length")
    if int(runs.sum()) != h * w:
        raise ValueError(f"run lengths add up to {int(runs.sum())}, but the mask is {h}x{w} = {h * w} pixels")
    values = (np.arange(len(runs)) % 2).astype(bool)
    flat = np.repeat(values, runs)
    return flat.reshape((w, h)).T.copy()


def rle_string_encode(counts: list[int]) -> str:
    """COCO's compressed RLE string: each count (from the third on, as the difference to the
    count two before) in 5-bit little-endian groups with a continuation bit, offset by 48."""
    out = []
    for i, c in enumerate(counts):
        x = int(c) - (int(counts[i - 2]) if i > 2 else 0)
        more = True
        while more:
            ch = x & 0x1F
            x >>= 5
            more = (x != -1) if (ch & 0x10) else (x != 0)
            if more:
                ch |= 0x20
            out.append(chr(ch + 48))
    return "".join(out)


def rle_string_decode(s: str) -> list[int]:
    """Inverse of ``rle_string_encode``. Raises ValueError on a malformed string."""
    counts: list[int] = []
    p = 0
    n = len(s)
    while p < n:
        x = 0
        k = 0
        more = True
        while more:
            if p >= n:
                raise ValueError("truncated RLE string")
            c = ord(s[p]) - 48
            if not 0 <= c < 64:
                raise ValueError(f"character {s[p]!r} is not valid in a COCO RLE string")
            x |= (c & 0x1F) << (5 * k)
            more = bool(c & 0x20)
            p += 1
            k += 1
            if not more and (c & 0x10):
                x |= -1 << (5 * k)
        if len(counts) > 2:
            x += counts[-2]
        counts.append(x)
    return counts


# -- reading -----------------------------------------------------------------------------------


def _check_stack(path: Path, masks: np.ndarray, ids: np.ndarray, hw: tuple[int, int] | None) -> None:
    if hw is not None and masks.shape[1:] != tuple(hw):
        raise SceneFileError(
            path, f"masks are {masks.shape[2]}x{masks.shape[1]} but the view's image is {hw[1]}x{hw[0]}"
        )
    if len(ids) and (ids.min() < 0 or ids.max() > MAX_MASK_ID):
        bad = ids[(ids < 0) | (ids > MAX_MASK_ID)]
        raise SceneFileError(path, f"mask ids out of range 0..{MAX_MASK_ID}: {bad[:5].tolist()}")
    if len(np.unique(ids)) != len(ids):
        raise SceneFileError(path, f"duplicate mask ids {ids.tolist()}")
    empty = np.flatnonzero(masks.reshape(len(masks), -1).sum(axis=1) == 0)
    if len(empty):
        raise SceneFileError(path, f"empty masks (no pixel set): ids {ids[empty][:10].tolist()}")


def read_png_masks(folder: str | Path, frame: int, hw: tuple[int, int] | None = None) -> MaskCandidates:
    """Candidates of ``frame`` from a sample-layout mask folder (no file for the frame: 0 masks)."""
    from clutt3r_core.io.images import read_mask

    folder = Path(folder)
    if not folder.is_dir():
        raise SceneFileError(folder, "mask folder not found")
    items = []
    for p in sorted(folder.iterdir()):
        m = _MASK_NAME.match(p.name)
        if m and int(m.group(1)) == int(frame):
            items.append((int(m.group(2)), p))
    if not items:
        if hw is None:
            raise SceneFileError(folder, f"no mask_{int(frame):06d}_MM.png files for frame {frame}")
        return MaskCandidates.empty(*hw)
    masks = []
    for mid, p in items:
        m = read_mask(p, hw)
        if mid > MAX_MASK_ID:
            raise SceneFileError(p, f"mask id {mid} out of range 0..{MAX_MASK_ID}")
        if not m.any():
            raise SceneFileError(p, "empty mask (no pixel is set)")
        masks.append(m)
    return MaskCandidates(np.stack(masks), np.array([i for i, _ in items], np.int32))


def read_npz_masks(path: str | Path, hw: tuple[int, int] | None = None) -> MaskCandidates:
    """Candidates of one view from a stacked npz (module docstring)."""
    path = Path(path)
    if not path.is_file():
        raise SceneFileError(path, "file not found")
    try:
        with np.load(path, allow_pickle=False) as z:
            data = {k: z[k] for k in z.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as e:
        raise SceneFileError(path, f"not a readable npz file ({e})") from None
    scores = None
    if "masks" in data:
        masks = data["masks"]
        if masks.ndim != 3:
            raise SceneFileError(path, f"'masks' must be (M, H, W), got shape {masks.shape}")
        if masks.dtype != bool and not np.isin(masks, (0, 1, 255)).all():
            raise SceneFileError(path, "'masks' must be binary (bool, 0/1 or 0/255)")
        masks = masks.astype(bool)
        ids = data.get("ids", np.arange(1, len(masks) + 1))
        ids = np.asarray(ids).reshape(-1)
        if len(ids) != len(masks):
            raise SceneFileError(path, f"{len(masks)} masks but {len(ids)} ids")
        if "scores" in data:
            scores = np.asarray(data["scores"], np.float32).reshape(-1)
            if len(scores) != len(masks):
                raise SceneFileError(path, f"{len(masks)} masks but {len(scores)} scores")
    elif "labels" in data:
        lab = data["labels"]
        if lab.ndim != 2 or not np.issubdtype(lab.dtype, np.integer):
            raise SceneFileError(path, f"'labels' must be an (H, W) integer map, got {lab.dtype} {lab.shape}")
        if lab.size and lab.min() < 0:
            raise SceneFileError(path, f"label ids out of range: {int(lab.min())} (0 = no mask, k > 0 = mask k)")
        ids = np.unique(lab)
        ids = ids[ids > 0]
        masks = lab[None, :, :] == ids[:, None, None] if len(ids) else np.zeros((0, *lab.shape), bool)
    else:
        raise SceneFileError(path, f"needs an array 'masks' (M, H, W) or 'labels' (H, W); it has {sorted(data)}")
    if not np.issubdtype(np.asarray(ids).dtype, np.integer):
        raise SceneFileError(path, f"'ids' must be integers, got {np.asarray(ids).dtype}")
    ids = np.asarray(ids, np.int64)
    _check_stack(path, masks, ids, hw)
    return MaskCandidates(masks, ids.astype(np.int32), scores)


def _decode_segmentation(seg: object, hw: tuple[int, int] | None, path: Path, where: str) -> np.ndarray:
    if isinstance(seg, dict):
        try:
            size = (int(seg["size"][0]), int(seg["size"][1]))
            counts = seg["counts"]
        except (KeyError, TypeError, ValueError, IndexError):
            raise SceneFileError(path, f"{where}: RLE needs 'size' [h, w] and 'counts'") from None
        if hw is not None and size != tuple(hw):
            raise SceneFileError(path, f"{where}: mask is {size[1]}x{size[0]} but the view's image is {hw[1]}x{hw[0]}")
        try:
            if isinstance(counts, str):
                counts = rle_string_decode(counts)
            elif isinstance(counts, bytes):
                counts = rle_string_decode(counts.decode("ascii"))
            return rle_decode(counts, size)
        except (ValueError, TypeError) as e:
            raise SceneFileError(path, f"{where}: bad RLE ({e})") from None
    if isinstance(seg, list):  # polygons [[x0, y0, x1, y1, ...], ...]
        if hw is None:
            raise SceneFileError(path, f"{where}: a polygon mask needs the image size (none known)")
        import cv2

        m = np.zeros(hw, np.uint8)
        try:
            polys = [np.asarray(p, np.float64).reshape(-1, 2) for p in seg]
        except (ValueError, TypeError):
            raise SceneFileError(path, f"{where}: polygons must be lists of x, y numbers") from None
        cv2.fillPoly(m, [np.round(p).astype(np.int32) for p in polys if len(p) >= 3], 1)
        return m.astype(bool)
    raise SceneFileError(path, f"{where}: 'segmentation' must be an RLE dict or a polygon list")


def read_coco_masks(
    path: str | Path, hw: tuple[int, int] | None = None, *, frame: int | None = None, image_name: str | None = None
) -> MaskCandidates:
    """Candidates of one view from a COCO-style JSON (module docstring).

    A plain list of records is one view. A dict with ``annotations`` may hold many views:
    records are kept whose ``image_id`` equals ``frame``, or whose image's ``file_name``
    ends with ``image_name``. Ids: a record's ``id`` when every record has a distinct one,
    else 1..M in file order.
    """
    path = Path(path)
    if not path.is_file():
        raise SceneFileError(path, "file not found")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise SceneFileError(path, f"not valid JSON ({e})") from None
    if isinstance(raw, dict) and "annotations" in raw:
        anns = raw["annotations"]
        if not isinstance(anns, list):
            raise SceneFileError(path, "'annotations' must be a list")
        if frame is not None or image_name is not None:
            wanted: set = set()
            if image_name is not None:
                for im in raw.get("images", []) or []:
                    if isinstance(im, dict) and str(im.get("file_name", "")).endswith(image_name):
                        wanted.add(im.get("id"))
            if not wanted and frame is not None:
                wanted = {frame}
            anns = [a for a in anns if isinstance(a, dict) and a.get("image_id") in wanted]
    elif isinstance(raw, list):
        anns = raw
    elif isinstance(raw, dict) and "segmentation" in raw:
        anns = [raw]
    else:
        raise SceneFileError(path, "expected a list of mask records or a COCO dict with 'annotations'")
    masks, scores, ids = [], [], []
    for i, a in enumerate(anns):
        if not isinstance(a, dict) or "segmentation" not in a:
            raise SceneFileError(path, f"record {i} has no 'segmentation'")
        m = _decode_segmentation(a["segmentation"], hw, path, f"record {i}")
        masks.append(m)
        s = a.get("score", a.get("predicted_iou"))
        scores.append(np.nan if s is None else float(s))
        ids.append(a.get("id"))
    if not masks:
        if hw is None:
            raise SceneFileError(path, "no mask records for this view")
        return MaskCandidates.empty(*hw)
    shapes = {m.shape for m in masks}
    if len(shapes) > 1:
        raise SceneFileError(path, f"records have different sizes {sorted(shapes)}")
    try:
        ids_arr = np.asarray(ids, np.int64)
        if len(np.unique(ids_arr)) != len(ids_arr):
            raise TypeError
    except (TypeError, ValueError):
        ids_arr = np.arange(1, len(masks) + 1)
    stack = np.stack(masks)
    _check_stack(path, stack, ids_arr, hw)
    sc = np.asarray(scores, np.float32)
    return MaskCandidates(stack, ids_arr.astype(np.int32), None if np.isnan(sc).any() else sc)


# -- writing -----------------------------------------------------------------------------------


def write_png_masks(folder: str | Path, frame: int, cands: MaskCandidates) -> list[Path]:
    """Write a view's candidates into a sample-layout mask folder (atomic per file)."""
    from clutt3r_core.io.images import write_png

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for mid, m in zip(cands.ids, cands.masks):
        p = folder / mask_png_name(frame, int(mid))
        write_png(p, m)
        out.append(p)
    return out


def write_npz_masks(path: str | Path, cands: MaskCandidates) -> Path:
    from clutt3r_core.io.images import atomic_write_npz

    arrays = {"masks": cands.masks, "ids": cands.ids}
    if cands.scores is not None:
        arrays["scores"] = cands.scores
    atomic_write_npz(path, **arrays)
    return Path(path)


def write_coco_masks(path: str | Path, cands: MaskCandidates) -> Path:
    """A list of COCO records with compressed RLE (what SAM's ``coco_rle`` output looks like)."""
    from clutt3r_core.io.images import atomic_write_bytes

    h, w = cands.shape
    recs = []
    for k, (mid, m) in enumerate(zip(cands.ids, cands.masks)):
        ys, xs = np.nonzero(m)
        rec = {
            "id": int(mid),
            "segmentation": {"size": [h, w], "counts": rle_string_encode(rle_encode(m))},
            "area": int(m.sum()),
            "bbox": [int(xs.min()), int(ys.min()), int(xs.max() - xs.min() + 1), int(ys.max() - ys.min() + 1)]
            if len(xs) else [0, 0, 0, 0],
        }
        if cands.scores is not None:
            rec["score"] = float(cands.scores[k])
        recs.append(rec)
    atomic_write_bytes(path, json.dumps(recs).encode())
    return Path(path)


def frame_of(path: Path) -> int | None:
    """The last number in a file name's stem (``masks_000003.npz`` -> 3), or None."""
    m = _LAST_NUMBER.search(path.stem)
    return int(m.group(1)) if m else None
