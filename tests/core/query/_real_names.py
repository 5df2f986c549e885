"""Everyday names of the objects in the two real samples, each pinned to a pixel of frame 0
(u, v) that lies on the object (named by looking at the images). An instance is the right
answer to a name when its frame-0 mask covers that pixel, so the test does not depend on
instance numbering."""

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


def instances_at(seg, scene, frame: int, u: int, v: int) -> set[int]:
    """Instances whose mask in ``frame`` covers pixel (u, v)."""
    view = next(x for x in scene.initial_views if x.frame == frame)
    tr = seg.trace
    out = set()
    for k in range(seg.num_instances):
        for n in seg.instance_nodes(k):
            if int(tr.nodes.frame[n]) != frame:
                continue
            m = view.masks.masks[view.masks.index_of(int(tr.nodes.mask_id[n]))]
            if m[v, u]:
                out.add(k)
    return out


def first_frame(scene) -> int:
    return int(min(v.frame for v in scene.initial_views))


def right_instances(seg, scene, names) -> dict[str, set[int]]:
    """Per name, the instances that cover its pixel; an instance that covers the pixels of two
    or more named objects (a union, e.g. mustard bottle + banana) is not a right answer unless
    nothing else covers the pixel."""
    f = first_frame(scene)
    cover = {name: instances_at(seg, scene, f, u, v) for name, u, v in names}
    count: dict[int, int] = {}
    for ks in cover.values():
        for k in ks:
            count[k] = count.get(k, 0) + 1
    return {name: ({k for k in ks if count[k] == 1} or ks) for name, ks in cover.items()}


__all__ = ["SEQ1", "SEQ4", "instances_at", "right_instances", "first_frame", "np"]
