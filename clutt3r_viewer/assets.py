"""Assets from the repository's ``static/`` folder: the title-bar logo and the gripper mesh.

``static/`` sits beside the packages (the design card's layout); an editable install finds it.
When it is missing (a wheel install), the viewer falls back to no logo and a line-drawn gripper.
"""

from __future__ import annotations

import base64
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["STATIC", "logo_data_uri", "gripper_parts", "gripper_mesh"]

STATIC = Path(__file__).resolve().parents[1] / "static"


@lru_cache(maxsize=1)
def logo_data_uri() -> str | None:
    p = STATIC / "clutt3r-logo.svg"
    if not p.is_file():
        return None
    return "data:image/svg+xml;base64," + base64.b64encode(p.read_bytes()).decode()


@lru_cache(maxsize=1)
def gripper_parts() -> dict[str, tuple[np.ndarray, np.ndarray]] | None:
    """name -> (vertices (V, 3) float64 metres, faces (F, 3) int32) from static/gripper.obj."""
    p = STATIC / "gripper.obj"
    if not p.is_file():
        return None
    parts: dict[str, tuple[list, list]] = {}
    name, base, count = None, 1, 0
    for line in p.read_text().splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "o":
            if name is not None:
                base += len(parts[name][0])
            name = tok[1]
            parts[name] = ([], [])
        elif tok[0] == "v" and name is not None:
            parts[name][0].append([float(x) for x in tok[1:4]])
        elif tok[0] == "f" and name is not None:
            parts[name][1].append([int(x.split("/")[0]) - base for x in tok[1:4]])
        count += 1
    return {k: (np.asarray(v, np.float64), np.asarray(f, np.int32)) for k, (v, f) in parts.items()}


def gripper_mesh(T_world_gripper: np.ndarray, width: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices (V, 3) float32 world, faces (F, 3) int32) of the gripper opened to ``width`` metres.

    Fingers move to x = -/+ width / 2; the palm keeps its size (docs/conventions.md, "Gripper").
    """
    parts = gripper_parts()
    if parts is None:
        return None
    nominal = float(parts["finger_right"][0][:, 0].min() - parts["finger_left"][0][:, 0].max())
    shift = (float(width) - nominal) / 2
    verts, faces, offset = [], [], 0
    for name, (v, f) in parts.items():
        v = v.copy()
        if name == "finger_left":
            v[:, 0] -= shift
        elif name == "finger_right":
            v[:, 0] += shift
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    V = np.concatenate(verts)
    V = V @ np.asarray(T_world_gripper)[:3, :3].T + np.asarray(T_world_gripper)[:3, 3]
    return V.astype(np.float32), np.concatenate(faces).astype(np.int32)
