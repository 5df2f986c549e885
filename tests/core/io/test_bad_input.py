"""Bad input: every broken scene folder must fail with a SceneFileError naming the file and the problem.

Each case writes a valid tiny sample-layout scene (or BOP scene), breaks exactly one
thing, and checks the message. No traceback from inside numpy or cv2 may escape.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io import load_bop_scene, load_scene
from clutt3r_core.io.images import write_png
from clutt3r_core.io.sample_layout import load_sample_layout, write_sample_layout
from clutt3r_core.scene import Camera, MaskCandidates, Scene, View

W, H = 32, 24
K = np.array([[30.0, 0.0, 15.5], [0.0, 30.0, 11.5], [0.0, 0.0, 1.0]])


def _pose(tx: float) -> np.ndarray:
    T = np.eye(4)
    T[0, 3] = tx
    return T


def _tiny_scene() -> Scene:
    """Three views: frames 0 and 1 initial (depth, two masks each), frame 2 post (RGB only)."""
    rng = np.random.default_rng(0)
    views = []
    for f in range(3):
        rgb = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        depth = np.full((H, W), 0.5, np.float32) if f < 2 else None
        m = np.zeros((2, H, W), bool)
        m[0, 2:10, 2:10] = True
        m[1, 12:20, 14:28] = True
        views.append(
            View(frame=f, rgb=rgb, camera=Camera(K, W, H, _pose(0.05 * f)), depth=depth,
                 masks=MaskCandidates(m, np.array([1, 2], np.int32)), name=f"image_{f:06d}.png")
        )
    return Scene(views=tuple(views), initial=(0, 1), post=(2,), name="tiny")


@pytest.fixture
def scene_dir(tmp_path: Path) -> Path:
    root = write_sample_layout(_tiny_scene(), tmp_path / "scene")
    # sanity: the unbroken folder loads
    s = load_sample_layout(root)
    assert len(s.views) == 3 and s.initial == (0, 1) and s.post == (2,)
    return root


def _load_error(root: Path) -> SceneFileError:
    with pytest.raises(SceneFileError) as ei:
        load_sample_layout(root)
    return ei.value


def _edit_transforms(root: Path, edit) -> None:
    p = root / "transforms.json"
    meta = json.loads(p.read_text())
    edit(meta)
    p.write_text(json.dumps(meta))


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])


# ---------------------------------------------------------------- sample layout


def test_missing_transforms_json(scene_dir):
    (scene_dir / "transforms.json").unlink()
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json"
    assert "missing" in str(e) and "transforms.json" in str(e)


def test_load_scene_names_folder_without_camera_file(scene_dir):
    (scene_dir / "transforms.json").unlink()
    with pytest.raises(SceneFileError) as ei:
        load_scene(scene_dir)
    assert str(scene_dir) in str(ei.value)
    assert "transforms.json" in str(ei.value) and "scene_camera.json" in str(ei.value)


def test_missing_scene_folder(tmp_path):
    with pytest.raises(SceneFileError, match="scene folder not found"):
        load_scene(tmp_path / "nope")


def test_invalid_json(scene_dir):
    (scene_dir / "transforms.json").write_text('{"frames": [')
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json" and "not valid JSON" in str(e)


def test_binary_garbage_json(scene_dir):
    (scene_dir / "transforms.json").write_bytes(b"\x89PNG\r\n\x1a\n\xff\xfe")
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json" and "not valid JSON" in str(e)


def test_transforms_without_frames(scene_dir):
    (scene_dir / "transforms.json").write_text('{"fl_x": 30}')
    e = _load_error(scene_dir)
    assert "transforms.json" in str(e) and "no 'frames' list" in str(e)


def test_image_size_differs_from_w_h(scene_dir):
    write_png(scene_dir / "images" / "image_000001.png", np.zeros((10, 20, 3), np.uint8))
    e = _load_error(scene_dir)
    assert e.path.name == "image_000001.png"
    assert "image is 20x10 but 32x24 was expected" in str(e)


def test_depth_png_not_16_bit(scene_dir):
    write_png(scene_dir / "depth" / "depth_000000.png", np.full((H, W), 50, np.uint8))
    e = _load_error(scene_dir)
    assert e.path.name == "depth_000000.png"
    assert "16-bit" in str(e) and "uint8" in str(e)


def test_mask_size_differs_from_image(scene_dir):
    write_png(scene_dir / "instance_masks" / "mask_000001_02.png", np.zeros((H + 1, W), bool))
    e = _load_error(scene_dir)
    assert e.path.name == "mask_000001_02.png"
    assert "mask is 32x25 but 32x24 was expected" in str(e)


@pytest.mark.parametrize(
    "bad",
    [
        np.diag([2.0, 2.0, 2.0, 1.0]),  # scaled
        np.array([[1, 0.3, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]]),  # sheared
        np.diag([1.0, 1.0, -1.0, 1.0]),  # mirrored (det -1)
    ],
    ids=["scaled", "sheared", "mirrored"],
)
def test_non_rigid_transform(scene_dir, bad):
    def edit(meta):
        meta["frames"][1]["transform_matrix"] = bad.tolist()

    _edit_transforms(scene_dir, edit)
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json"
    assert "frame 1 (images/image_000001.png)" in str(e) and "not rigid" in str(e)


def test_transform_matrix_not_numeric(scene_dir):
    def edit(meta):
        meta["frames"][0]["transform_matrix"] = [["a", 0, 0, 0]] * 4

    _edit_transforms(scene_dir, edit)
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json"
    assert "frame 0" in str(e) and "transform_matrix" in str(e) and "4x4" in str(e)


def test_transform_matrix_wrong_shape(scene_dir):
    def edit(meta):
        meta["frames"][0]["transform_matrix"] = np.eye(4)[:3].tolist()

    _edit_transforms(scene_dir, edit)
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json" and "must be 4x4" in str(e)


def test_intrinsics_not_numeric(scene_dir):
    _edit_transforms(scene_dir, lambda meta: meta.update(fl_x="wide"))
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json" and "'fl_x'" in str(e) and "number" in str(e)


def test_intrinsics_missing(scene_dir):
    _edit_transforms(scene_dir, lambda meta: meta.pop("cy"))
    e = _load_error(scene_dir)
    assert e.path.name == "transforms.json" and "missing intrinsics key 'cy'" in str(e)


def test_empty_instance_masks_folder(scene_dir):
    for p in (scene_dir / "instance_masks").iterdir():
        p.unlink()
    e = _load_error(scene_dir)
    assert e.path.name == "instance_masks" and "mask folder is empty" in str(e)


@pytest.mark.parametrize(
    "rel",
    ["images/image_000001.png", "depth/depth_000001.png", "instance_masks/mask_000000_01.png"],
    ids=["image", "depth", "mask"],
)
def test_truncated_png(scene_dir, rel):
    _truncate(scene_dir / rel)
    e = _load_error(scene_dir)
    assert e.path == scene_dir / rel
    assert "corrupt or truncated" in str(e)


def test_empty_png_file(scene_dir):
    (scene_dir / "images" / "image_000000.png").write_bytes(b"")
    e = _load_error(scene_dir)
    assert e.path.name == "image_000000.png" and "file is empty" in str(e)


def test_missing_image_file(scene_dir):
    (scene_dir / "images" / "image_000002.png").unlink()
    e = _load_error(scene_dir)
    assert e.path.name == "image_000002.png" and "file not found" in str(e)


def test_missing_depth_of_initial_frame(scene_dir):
    (scene_dir / "depth" / "depth_000001.png").unlink()
    e = _load_error(scene_dir)
    assert e.path.name == "depth_000001.png" and "initial frame 1 has no depth file" in str(e)


def test_camera_width_height_swapped(scene_dir):
    _edit_transforms(scene_dir, lambda meta: meta.update(w=H, h=W))
    e = _load_error(scene_dir)
    assert e.path.name == "image_000000.png"
    assert "image is 32x24 but 24x32 was expected" in str(e)


def test_camera_file_lists_more_frames_than_images(scene_dir):
    def edit(meta):
        extra = dict(meta["frames"][2])
        extra["file_path"] = "images/image_000005.png"
        extra["depth_file_path"] = "depth/depth_000005.png"
        meta["frames"].append(extra)

    _edit_transforms(scene_dir, edit)
    e = _load_error(scene_dir)
    assert e.path.name == "image_000005.png" and "file not found" in str(e)


def test_instance_tree_names_unknown_frames(scene_dir):
    (scene_dir / "clutt3r_scene.json").unlink()
    tree = {"schema_version": 1, "initial": {"initial_idx": [0, 1, 7]}, "updates": {"2": {}, "9": {}}}
    (scene_dir / "instance_tree.json").write_text(json.dumps(tree))
    e = _load_error(scene_dir)
    assert e.path.name == "instance_tree.json"
    assert "frames [7, 9]" in str(e) and "transforms.json does not list" in str(e)


def test_instance_tree_without_initial_idx(scene_dir):
    (scene_dir / "clutt3r_scene.json").unlink()
    (scene_dir / "instance_tree.json").write_text(json.dumps({"schema_version": 1}))
    e = _load_error(scene_dir)
    assert e.path.name == "instance_tree.json" and "initial.initial_idx" in str(e)


def test_scene_sidecar_names_unknown_frames(scene_dir):
    (scene_dir / "clutt3r_scene.json").write_text(json.dumps({"initial_frames": [0, 4], "post_frames": [2]}))
    e = _load_error(scene_dir)
    assert e.path.name == "clutt3r_scene.json" and "frames [4]" in str(e)


def test_scene_sidecar_frame_both_initial_and_post(scene_dir):
    (scene_dir / "clutt3r_scene.json").write_text(json.dumps({"initial_frames": [0, 1], "post_frames": [1, 2]}))
    e = _load_error(scene_dir)
    assert e.path.name == "clutt3r_scene.json" and "both initial and post" in str(e)


def test_corrupt_gt_points(scene_dir):
    (scene_dir / "gt").mkdir()
    (scene_dir / "gt" / "objects.json").write_text("[]")
    (scene_dir / "gt" / "points.npz").write_bytes(b"PK\x03\x04 this is not a zip file")
    e = _load_error(scene_dir)
    assert e.path.name == "points.npz" and "unreadable" in str(e)


def test_errors_are_scene_errors():
    # callers may catch the broad class
    assert issubclass(SceneFileError, SceneError) and issubclass(SceneFileError, ValueError)


# ---------------------------------------------------------------- BOP


def _write_bop(root: Path) -> Path:
    root.mkdir(parents=True)
    cams = {}
    for im in range(2):
        write_png(root / "rgb" / f"{im:06d}.png", np.zeros((H, W, 3), np.uint8))
        write_png(root / "depth" / f"{im:06d}.png", np.full((H, W), 500, np.uint16))
        cams[str(im)] = {"cam_K": K.reshape(-1).tolist(), "cam_R_w2c": np.eye(3).reshape(-1).tolist(),
                         "cam_t_w2c": [0.0, 0.0, 0.0], "depth_scale": 1.0}
    (root / "scene_camera.json").write_text(json.dumps(cams))
    assert len(load_bop_scene(root).views) == 2
    return root


def _bop_error(root: Path) -> SceneFileError:
    with pytest.raises(SceneFileError) as ei:
        load_bop_scene(root)
    return ei.value


def test_bop_missing_scene_camera(tmp_path):
    root = _write_bop(tmp_path / "000001")
    (root / "scene_camera.json").unlink()
    e = _bop_error(root)
    assert e.path.name == "scene_camera.json" and "missing" in str(e)


def test_bop_missing_cam_k(tmp_path):
    root = _write_bop(tmp_path / "000001")
    cams = json.loads((root / "scene_camera.json").read_text())
    del cams["1"]["cam_K"]
    (root / "scene_camera.json").write_text(json.dumps(cams))
    e = _bop_error(root)
    assert e.path.name == "scene_camera.json" and "image 1" in str(e) and "'cam_K'" in str(e)


def test_bop_cam_k_wrong_length(tmp_path):
    root = _write_bop(tmp_path / "000001")
    cams = json.loads((root / "scene_camera.json").read_text())
    cams["0"]["cam_K"] = [1, 2, 3]
    (root / "scene_camera.json").write_text(json.dumps(cams))
    e = _bop_error(root)
    assert e.path.name == "scene_camera.json" and "'cam_K'" in str(e) and "9 numbers" in str(e)


def test_bop_missing_camera_pose(tmp_path):
    root = _write_bop(tmp_path / "000001")
    cams = json.loads((root / "scene_camera.json").read_text())
    del cams["0"]["cam_t_w2c"]
    (root / "scene_camera.json").write_text(json.dumps(cams))
    e = _bop_error(root)
    assert e.path.name == "scene_camera.json" and "'cam_t_w2c'" in str(e)


def test_bop_non_rigid_camera_rotation(tmp_path):
    root = _write_bop(tmp_path / "000001")
    cams = json.loads((root / "scene_camera.json").read_text())
    cams["1"]["cam_R_w2c"] = (2 * np.eye(3)).reshape(-1).tolist()
    (root / "scene_camera.json").write_text(json.dumps(cams))
    e = _bop_error(root)
    assert e.path.name == "scene_camera.json" and "image 1" in str(e) and "not rigid" in str(e)


def test_bop_depth_not_16_bit(tmp_path):
    root = _write_bop(tmp_path / "000001")
    write_png(root / "depth" / "000001.png", np.full((H, W), 50, np.uint8))
    e = _bop_error(root)
    assert e.path.name == "000001.png" and e.path.parent.name == "depth" and "16-bit" in str(e)


def test_bop_missing_rgb(tmp_path):
    root = _write_bop(tmp_path / "000001")
    (root / "rgb" / "000000.png").unlink()
    e = _bop_error(root)
    assert e.path.parent.name == "rgb" and "000000" in str(e) and "not found" in str(e)


def test_bop_invalid_json(tmp_path):
    root = _write_bop(tmp_path / "000001")
    (root / "scene_camera.json").write_text("{")
    e = _bop_error(root)
    assert e.path.name == "scene_camera.json" and "not valid JSON" in str(e)


def test_bop_requested_frame_missing(tmp_path):
    root = _write_bop(tmp_path / "000001")
    with pytest.raises(SceneFileError) as ei:
        load_bop_scene(root, frames=[0, 5])
    assert ei.value.path.name == "scene_camera.json" and "[5]" in str(ei.value)


def test_bop_truncated_mask(tmp_path):
    root = _write_bop(tmp_path / "000001")
    gt = {str(im): [{"obj_id": 3, "cam_R_m2c": np.eye(3).reshape(-1).tolist(), "cam_t_m2c": [0, 0, 500]}]
          for im in range(2)}
    (root / "scene_gt.json").write_text(json.dumps(gt))
    for im in range(2):
        write_png(root / "mask_visib" / f"{im:06d}_000000.png", np.ones((H, W), bool))
    assert load_bop_scene(root).ground_truth is not None
    _truncate(root / "mask_visib" / "000001_000000.png")
    e = _bop_error(root)
    assert e.path.name == "000001_000000.png" and "corrupt or truncated" in str(e)


def test_bop_missing_depth_of_initial_image(tmp_path):
    root = _write_bop(tmp_path / "000001")
    (root / "depth" / "000000.png").unlink()
    e = _bop_error(root)
    assert e.path.name == "000000.png" and "initial image 0 has no depth file" in str(e)


def test_bop_gt_instances_differ_between_images(tmp_path):
    root = _write_bop(tmp_path / "000001")
    inst = {"obj_id": 3, "cam_R_m2c": np.eye(3).reshape(-1).tolist(), "cam_t_m2c": [0, 0, 500]}
    (root / "scene_gt.json").write_text(json.dumps({"0": [inst], "1": [dict(inst, obj_id=4)]}))
    e = _bop_error(root)
    assert e.path.name == "scene_gt.json" and "image 1 lists objects [4] but image 0 lists [3]" in str(e)


def test_bop_missing_visible_mask(tmp_path):
    root = _write_bop(tmp_path / "000001")
    inst = {"obj_id": 3, "cam_R_m2c": np.eye(3).reshape(-1).tolist(), "cam_t_m2c": [0, 0, 500]}
    (root / "scene_gt.json").write_text(json.dumps({"0": [inst], "1": [inst]}))
    write_png(root / "mask_visib" / "000000_000000.png", np.ones((H, W), bool))
    e = _bop_error(root)
    assert e.path.name == "000001_000000.png" and "file not found" in str(e)


def test_load_scene_detects_sample_layout(tmp_path):
    root = write_sample_layout(_tiny_scene(), tmp_path / "sample_x" / "data")
    for p in (root, root / "transforms.json", root.parent):  # folder, camera file, release folder
        s = load_scene(p)
        assert [v.frame for v in s.views] == [0, 1, 2] and s.root == root
