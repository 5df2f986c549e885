"""Everyday names of the objects in the two real samples, each pinned to a pixel of frame 0
(u, v) that lies on the object (named by looking at the images). The pixel is lifted to 3D
with frame 0's depth; an instance is a right answer to a name when it has fused points
within 1 cm of that 3D point, so the test does not depend on instance numbering."""

from __future__ import annotations

import numpy as np

SEQ1 = (  # 640 x 480, the authors' own capture
    ("tennis ball", 425, 235),
    ("tuna can", 370, 75),
    ("sugar box", 190, 270),
    ("orange", 335, 125),
    ("white bottle", 195, 160),
    ("clamp", 470, 175),
    ("blue cup", 265, 95),
    ("red mug", 305, 215),
    ("marker", 340, 292),
)

SEQ4 = (  # 1920 x 1080, GraspClutter6D easy scene
    ("mustard bottle", 923, 251),
    ("banana", 910, 475),  # two bananas: either is a right answer
    ("banana", 1075, 448),
    ("orange", 1167, 327),
    ("plum", 976, 429),
    ("wrench", 1147, 422),
    ("knife", 1385, 323),
    ("fork", 1299, 488),
    ("tuna can", 1207, 547),
    ("coffee can", 1160, 692),
    ("apple", 910, 630),
)


def instances_at(seg, scene, frame: int, u: int, v: int, radius: float = 0.01) -> set[int]:
    """Instances with fused points within ``radius`` metres of pixel (u, v) of ``frame`` lifted by its depth."""
    view = next(x for x in scene.initial_views if x.frame == frame)
    z = view.depth[max(v - 3, 0):v + 4, max(u - 3, 0):u + 4]
    z = float(np.nanmedian(z))
    cam = view.camera
    k = cam.K
    p_cam = np.array([(u - k[0, 2]) * z / k[0, 0], (v - k[1, 2]) * z / k[1, 1], z, 1.0])
    p = (cam.T_world_camera @ p_cam)[:3]
    near = np.linalg.norm(seg.points - p, axis=1) < radius
    return {int(i) for i in np.unique(seg.instance[near]) if i >= 0}


def first_frame(scene) -> int:
    return int(min(v.frame for v in scene.initial_views))


def right_instances(seg, scene, names) -> dict[str, set[int]]:
    """Per name, the instances that cover its pixel; an instance that covers the pixels of two
    or more named objects (a union, e.g. mustard bottle + banana) is not a right answer unless
    nothing else covers the pixel."""
    f = first_frame(scene)
    cover = [(name, instances_at(seg, scene, f, u, v)) for name, u, v in names]
    named: dict[int, set[str]] = {}
    for name, ks in cover:
        for k in ks:
            named.setdefault(k, set()).add(name)
    out: dict[str, set[int]] = {}
    for name, ks in cover:
        out.setdefault(name, set()).update({k for k in ks if len(named[k]) == 1} or ks)
    return out


__all__ = ["SEQ1", "SEQ4", "instances_at", "right_instances", "first_frame", "np"]
