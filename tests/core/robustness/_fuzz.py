"""Fuzzing harness of the scene loaders, shared by the CI test (bounded) and
``benchmarks/fuzz_loaders.py`` (a long run).

Two tiny valid scenes are written once per process: a sample-layout scene (2 views of
32x24 px, mask candidates, ground truth with objects.json, instance maps and points.npz)
and a BOP scene (the one of tests/core/io/test_bop.py: 3 views of 64x48 px, scene_gt.json,
visible masks). A corruption, drawn by hypothesis, breaks one file of a fresh copy:

* a JSON file (transforms.json, clutt3r_scene.json, gt/objects.json, scene_camera.json,
  scene_gt.json): one value anywhere in the tree replaced by any JSON value or deleted,
  or the text itself mutated byte-wise;
* a PNG (colour, depth, mask, ground-truth map): its bytes mutated (truncated, bytes
  overwritten / inserted / deleted), or replaced by a valid PNG of another dtype, channel
  count or size;
* an npz (gt/points.npz): its bytes mutated, or replaced by a valid npz of other arrays.

The property (``check_loads``): ``load_scene`` returns a Scene or raises a ``Clutt3rError``;
anything else (an IndexError from numpy, a cv2.error, a zipfile error ...) is a bug.

Run folders get the same treatment (``run_corruptions``, ``check_run_loads``): a run of a
two-view scene with run.json or trace/trace.json mutated as JSON, or instances.npz,
cloud.npz or trace/trace.npz mutated as npz; ``load_run`` must return a Segmentation or
raise a ``Clutt3rError`` (the viewer, query, grasp and update all read runs through it).
"""

from __future__ import annotations

import atexit
import copy
import functools
import io
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
from hypothesis import strategies as st

from clutt3r_core.errors import Clutt3rError
from clutt3r_core.io import load_scene, write_sample_layout
from clutt3r_core.scene import GroundTruth, ObjectInfo, Scene
from tests.core.io.test_bop import _write_bop_scene  # module level: it defines @given tests
from tests.core.robustness._scenes import BOXES, make_scene, render

JSON_FILES = {
    "sample": ("transforms.json", "clutt3r_scene.json", "gt/objects.json"),
    "bop": ("scene_camera.json", "scene_gt.json"),
}
PNG_FILES = {
    "sample": ("images/image_000001.png", "depth/depth_000000.png", "instance_masks/mask_000001_02.png",
               "gt/instance_000000.png"),
    "bop": ("rgb/000001.png", "depth/000002.png", "mask_visib/000000_000001.png"),
}
NPZ_FILES = {"sample": ("gt/points.npz",), "bop": ()}


@functools.lru_cache(maxsize=1)
def base_scenes() -> dict[str, Path]:
    """The two valid scene folders (written once per process, removed at exit)."""
    tmp = Path(tempfile.mkdtemp(prefix="clutt3r-fuzz-"))
    atexit.register(shutil.rmtree, tmp, True)
    sc = make_scene(2, width=32, height=24)
    maps = {v.frame: render(v.camera, BOXES)[1] - 1 for v in sc.views}  # -1 table/none, k box k
    gt = GroundTruth(
        objects=tuple(ObjectInfo(id=k, category="box", T_world_object=np.eye(4)) for k in range(len(BOXES))),
        instance_maps={f: np.maximum(m, -1) for f, m in maps.items()},
        points=np.zeros((4, 3), np.float32), point_labels=np.array([0, 1, -1, 0], np.int32),
    )
    sample = write_sample_layout(Scene(views=sc.views, initial=(0, 1), ground_truth=gt, name="fz"), tmp / "sample")
    bop = tmp / "bop" / "000001"
    _write_bop_scene(bop)
    for root in (sample, bop):
        load_scene(root)  # sanity: the unbroken folders load
    return {"sample": sample, "bop": bop}


RUN_JSON_FILES = ("run.json", "trace/trace.json")
RUN_NPZ_FILES = ("instances.npz", "cloud.npz", "trace/trace.npz")


@functools.lru_cache(maxsize=1)
def base_run() -> Path:
    """A valid run folder of a 2-view 160x120 scene (written once per process)."""
    from clutt3r_core.pipeline import segment
    from clutt3r_core.runs import save_run

    return save_run(segment(make_scene(2)), base_scenes()["sample"].parent / "run")


def check_run_loads(root: Path) -> str:
    """The run property: "ok" or "error" (a Clutt3rError); anything else propagates."""
    from clutt3r_core.runs import load_run

    try:
        load_run(root)
    except Clutt3rError:
        return "error"
    return "ok"


def check_loads(root: Path) -> str:
    """The property: returns "ok" or "error" (a Clutt3rError); anything else propagates."""
    try:
        load_scene(root)
    except Clutt3rError:
        return "error"
    return "ok"


# ------------------------------------------------------------------ corruptions

_json_leaf = (
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats() | st.text(max_size=12)
    | st.sampled_from([0, -1, 1, 2**31, 2**64, 1e308, -0.0, "", "1.5", "nan", "../../etc", "image_000000.png"])
)
json_values = st.recursive(
    _json_leaf, lambda c: st.lists(c, max_size=5) | st.dictionaries(st.text(max_size=10), c, max_size=4),
    max_leaves=10,
)


def _paths(obj, prefix=()):
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


@st.composite
def mutated_json(draw, obj):
    """``obj`` (parsed JSON) with one value anywhere replaced by any JSON value, or deleted."""
    obj = copy.deepcopy(obj)
    path = draw(st.sampled_from(list(_paths(obj))))
    value = draw(json_values)
    if not path:
        return value
    parent = functools.reduce(lambda o, k: o[k], path[:-1], obj)
    if draw(st.booleans()):
        del parent[path[-1]]
    else:
        parent[path[-1]] = value
    return obj


@st.composite
def mutated_bytes(draw, data: bytes) -> bytes:
    """``data`` after 1-3 edits: truncate, overwrite, insert, delete, or empty."""
    b = bytearray(data)
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(["truncate", "overwrite", "insert", "delete", "empty"]))
        n = len(b)
        if op == "empty" or n == 0:
            b = bytearray()
            break
        i = draw(st.integers(0, n - 1))
        if op == "truncate":
            del b[i:]
        elif op == "overwrite":
            chunk = draw(st.binary(min_size=1, max_size=8))
            b[i : i + len(chunk)] = chunk
        elif op == "insert":
            b[i:i] = draw(st.binary(min_size=1, max_size=16))
        else:
            del b[i : i + draw(st.integers(1, 64))]
    return bytes(b)


@st.composite
def other_png(draw) -> bytes:
    """A valid PNG of a random dtype, channel count and size (not what the loader expects)."""
    import cv2

    dtype = draw(st.sampled_from([np.uint8, np.uint16]))
    ch = draw(st.sampled_from([1, 3, 4]))
    h, w = draw(st.integers(1, 50)), draw(st.integers(1, 70))
    shape = (h, w) if ch == 1 else (h, w, ch)
    a = np.random.default_rng(draw(st.integers(0, 2**16))).integers(0, np.iinfo(dtype).max, shape, endpoint=True)
    ok, buf = cv2.imencode(".png", a.astype(dtype))
    assert ok
    return buf.tobytes()


@st.composite
def other_npz(draw) -> bytes:
    """A valid npz whose arrays have random names, shapes and dtypes."""
    names = draw(st.lists(st.sampled_from(["points", "labels", "x"]), min_size=0, max_size=3, unique=True))
    arrays = {}
    for name in names:
        dtype = draw(st.sampled_from([np.float32, np.float64, np.int32, np.int64, np.uint8, bool, np.complex64]))
        shape = tuple(draw(st.lists(st.integers(0, 5), min_size=0, max_size=3)))
        arrays[name] = np.ones(shape, dtype)
    buf = io.BytesIO()
    np.savez(buf, **arrays)
    return buf.getvalue()


@st.composite
def corruptions(draw, kinds=("json", "png", "npz")) -> tuple[str, str, bytes]:
    """(layout, file relative to the scene folder, its new bytes)."""
    roots = base_scenes()
    kind = draw(st.sampled_from(list(kinds)))
    table = {"json": JSON_FILES, "png": PNG_FILES, "npz": NPZ_FILES}[kind]
    layout = draw(st.sampled_from([k for k, v in table.items() if v]))
    rel = draw(st.sampled_from(table[layout]))
    data = (roots[layout] / rel).read_bytes()
    if kind == "json":
        if draw(st.booleans()):
            new = json.dumps(draw(mutated_json(json.loads(data)))).encode()
        else:
            new = draw(mutated_bytes(data))
    elif kind == "png":
        new = draw(mutated_bytes(data)) if draw(st.booleans()) else draw(other_png())
    else:
        new = draw(mutated_bytes(data)) if draw(st.booleans()) else draw(other_npz())
    return layout, rel, new


@st.composite
def run_corruptions(draw) -> tuple[str, str, bytes]:
    """("run", file relative to the run folder, its new bytes)."""
    base = base_run()
    if draw(st.booleans()):
        rel = draw(st.sampled_from(RUN_JSON_FILES))
        data = (base / rel).read_bytes()
        new = json.dumps(draw(mutated_json(json.loads(data)))).encode() if draw(st.booleans()) else draw(
            mutated_bytes(data))
    else:
        rel = draw(st.sampled_from(RUN_NPZ_FILES))
        data = (base / rel).read_bytes()
        new = draw(mutated_bytes(data)) if draw(st.booleans()) else draw(other_npz())
    return "run", rel, new


def apply(corruption: tuple[str, str, bytes], workdir: Path) -> Path:
    """A copy of the corruption's base scene in ``workdir`` with the file replaced; its root."""
    layout, rel, new = corruption
    root = workdir / layout
    if root.exists():
        shutil.rmtree(root)
    shutil.copytree(base_run() if layout == "run" else base_scenes()[layout], root)
    (root / rel).write_bytes(new)
    return root
