"""Write static/gripper.obj: the parallel-jaw gripper of docs/conventions.md ("Gripper"), in three named parts.

The numbers come from ``clutt3r_core.grasping.gripper.GripperGeometry`` (the one source the
planner and the evaluator use too): origin at the grasp centre (midpoint between the finger
pads), z = approach (palm towards fingertips), x = closing axis. Parts: ``finger_left``
(x < 0), ``finger_right`` and ``palm``, drawn fully open (width = ``max_width``); the viewer
moves the fingers to each grasp's width, the palm keeps its size. Run once; the output is committed:

    .venv/bin/python static/make_gripper.py
"""

from pathlib import Path

import trimesh

from clutt3r_core.grasping.gripper import FRANKA, GripperGeometry


def parts(geometry: GripperGeometry = FRANKA) -> dict[str, trimesh.Trimesh]:
    out = {}
    boxes = geometry.boxes(geometry.max_width)
    for name in ("palm", "finger_left", "finger_right"):
        b = boxes[name]
        m = trimesh.creation.box(extents=[2 * h for h in b.half])
        m.apply_translation(b.centre)
        out[name] = m
    return out


def write(path: Path, geometry: GripperGeometry = FRANKA) -> None:
    lines = [f"# Clutt3R parallel-jaw gripper (static/make_gripper.py, GripperGeometry); metres, z = approach, "
             f"x = closing, origin = grasp centre, opening {geometry.max_width} m"]
    offset = 1
    for name, m in parts(geometry).items():
        lines.append(f"o {name}")
        lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in m.vertices]
        lines += [f"f {a + offset} {b + offset} {c + offset}" for a, b, c in m.faces]
        offset += len(m.vertices)
    path.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    write(Path(__file__).with_name("gripper.obj"))
