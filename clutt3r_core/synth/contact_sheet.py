"""Contact sheet of a scene: per view the RGB image, the ground-truth instance map and the mask candidates.

Tiles are scaled to 320 px width and laid out two views per row (6 tiles). Mask
candidates are filled translucently and outlined; when the generation record is
known the colour encodes the kind (green proper, yellow part, magenta union, cyan
spurious, white table) and a letter marks each candidate (P, p, U, s, T).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_core.scene import Scene

__all__ = ["contact_sheet", "write_contact_sheet", "instance_colors"]

_TILE_W = 320
_KIND_COLOR = {"proper": (60, 220, 90), "part": (250, 210, 40), "union": (235, 60, 220),
               "spurious": (40, 220, 240), "table": (255, 255, 255)}
_KIND_LETTER = {"proper": "P", "part": "p", "union": "U", "spurious": "s", "table": "T"}


def instance_colors(n: int) -> np.ndarray:
    """(n, 3) uint8 distinct colours (golden-ratio hues), deterministic."""
    import colorsys

    h = (np.arange(n) * 0.618033988749895) % 1.0
    return np.array([[int(255 * c) for c in colorsys.hsv_to_rgb(x, 0.75, 0.95)] for x in h], np.uint8).reshape(-1, 3)


def _label(img: np.ndarray, text: str) -> None:
    import cv2

    cv2.putText(img, text, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 3, cv2.LINE_AA)
    cv2.putText(img, text, (5, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 1, cv2.LINE_AA)


def contact_sheet(scene: Scene, info=None) -> np.ndarray:
    """(H, W, 3) uint8 contact sheet of ``scene`` (``info``: optional ``SynthInfo``)."""
    import cv2

    gt = scene.ground_truth
    n_obj = len(gt.objects) if gt is not None else 0
    pal = instance_colors(max(n_obj, 1))
    post = set(scene.post)
    tiles = []
    for vi, v in enumerate(scene.views):
        H, W = v.camera.height, v.camera.width
        s = _TILE_W / W
        th = int(round(H * s))
        tag = f"f{v.frame}" + (" post" if vi in post else "")
        rgb = cv2.resize(v.rgb, (_TILE_W, th), interpolation=cv2.INTER_AREA)
        _label(rgb, tag + " rgb")
        gtimg = np.full((th, _TILE_W, 3), 40, np.uint8)
        if gt is not None and v.frame in gt.instance_maps:
            m = gt.instance_maps[v.frame]
            col = np.where((m >= 0)[..., None], pal[np.clip(m, 0, None) % len(pal)], 40).astype(np.uint8)
            gtimg = cv2.resize(col, (_TILE_W, th), interpolation=cv2.INTER_NEAREST)
            for k in np.unique(m[m >= 0]):
                vs, us = np.nonzero(m == k)
                cv2.putText(gtimg, str(k), (int(us.mean() * s) - 4, int(vs.mean() * s) + 4),
                            cv2.FONT_HERSHEY_SIMPLEX, 0.35, (0, 0, 0), 1, cv2.LINE_AA)
        _label(gtimg, tag + " gt")
        mimg = (rgb.astype(np.float32) * 0.45).astype(np.uint8)
        kinds = info.mask_kinds.get(v.frame) if info is not None else None
        if v.masks is not None and len(v.masks):
            big = cv2.resize(v.masks.masks.astype(np.uint8).transpose(1, 2, 0), (_TILE_W, th),
                             interpolation=cv2.INTER_NEAREST).reshape(th, _TILE_W, -1).transpose(2, 0, 1) > 0
            order = np.argsort(-big.reshape(len(big), -1).sum(1))  # big first, small on top
            rnd = instance_colors(len(big) + 3)[3:]
            fill = mimg.astype(np.float32)
            for j in order:
                kind = kinds[j] if kinds is not None else None
                c = np.asarray(_KIND_COLOR[kind] if kind else rnd[j], np.float32)
                if kind != "table":
                    fill[big[j]] = 0.65 * fill[big[j]] + 0.35 * c
            mimg = fill.astype(np.uint8)
            for j in order:
                kind = kinds[j] if kinds is not None else None
                c = tuple(int(x) for x in (_KIND_COLOR[kind] if kind else rnd[j]))
                cont, _ = cv2.findContours(big[j].astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
                cv2.drawContours(mimg, cont, -1, c, 1, cv2.LINE_AA)
                if kind and kind != "table":
                    vs, us = np.nonzero(big[j])
                    cv2.putText(mimg, _KIND_LETTER[kind], (int(us.mean()) - 3, int(vs.mean()) + 4),
                                cv2.FONT_HERSHEY_SIMPLEX, 0.35, c, 1, cv2.LINE_AA)
        _label(mimg, f"{tag} masks ({0 if v.masks is None else len(v.masks)})")
        tiles.append(np.concatenate([rgb, gtimg, mimg], axis=1))
    th = max(t.shape[0] for t in tiles)
    tiles = [np.pad(t, ((0, th - t.shape[0]), (0, 0), (0, 0))) for t in tiles]
    if len(tiles) % 2:
        tiles.append(np.zeros_like(tiles[0]))
    rows = [np.concatenate([tiles[i], np.full((th, 4, 3), 255, np.uint8), tiles[i + 1]], axis=1)
            for i in range(0, len(tiles), 2)]
    sheet = np.concatenate([np.pad(r, ((0, 4), (0, 0), (0, 0)), constant_values=255) for r in rows], axis=0)
    if info is not None:
        head = np.full((24, sheet.shape[1], 3), 255, np.uint8)
        txt = (f"{scene.name}: {n_obj} objects, mean occlusion {info.mean_occlusion:.1%}, "
               f"mask noise {info.config.mask_noise}, depth noise {info.config.depth_noise}")
        if info.interaction is not None:
            it = info.interaction
            txt += f"; removed {it.removed_object}, displaced {it.displaced_object}"
        cv2.putText(head, txt, (6, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
        sheet = np.concatenate([head, sheet], axis=0)
    return sheet


def write_contact_sheet(scene: Scene, path: str | Path, info=None) -> Path:
    """Write ``contact_sheet(scene, info)`` as a PNG (atomically)."""
    from clutt3r_core.io.images import write_png

    path = Path(path)
    write_png(path, contact_sheet(scene, info))
    return path
