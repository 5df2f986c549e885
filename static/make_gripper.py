"""Write static/gripper.obj: a parallel-jaw gripper in four named parts (run once; output is committed).

Gripper frame (the viewer's grasp convention): z = approach direction, x = closing direction,
fingertips at the origin. Parts: ``palm`` (spans the opening), ``finger_left`` (x < 0),
``finger_right`` (x > 0) and ``wrist``. The nominal opening is 0.08 m; the viewer moves the
fingers and stretches the palm to each grasp's width.
"""

from pathlib import Path

import trimesh

OPENING = 0.08
DEPTH = 0.05  # finger length, m
T = 0.008  # finger and palm thickness, m


def parts() -> dict[str, trimesh.Trimesh]:
    def box(extents, centre):
        m = trimesh.creation.box(extents=extents)
        m.apply_translation(centre)
        return m

    half = OPENING / 2
    return {
        "palm": box((OPENING + 2 * T, 0.02, T), (0, 0, -DEPTH - T / 2)),
        "finger_left": box((T, 0.02, DEPTH), (-half - T / 2, 0, -DEPTH / 2)),
        "finger_right": box((T, 0.02, DEPTH), (half + T / 2, 0, -DEPTH / 2)),
        "wrist": box((0.012, 0.012, DEPTH), (0, 0, -1.5 * DEPTH - T)),
    }


def write(path: Path) -> None:
    lines = ["# Clutt3R parallel-jaw gripper (static/make_gripper.py); metres, z = approach"]
    offset = 1
    for name, m in parts().items():
        lines.append(f"o {name}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in m.vertices]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in m.faces]
        offset += len(m.vertices)
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write(Path(__file__).with_name("gripper.obj"))
