"""BOP loader on a tiny BOP scene written by the test: a table plane z = 0 and two boxes,
seen by three 64x48 cameras. Depth and visible masks are ray-cast exactly, so every
number the loader produces can be checked against the generator.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from clutt3r_core.io import load_bop_scene, load_scene
from clutt3r_core.io.bop import paint_instances, voxel_labelled_points
from clutt3r_core.io.images import write_png

W, H = 64, 48
K = np.array([[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]])
# axis-aligned boxes (min xyz, max xyz) in world metres, standing on the table z = 0
BOXES = [np.array([[-0.06, -0.05, 0.0], [0.02, 0.03, 0.06]]), np.array([[0.04, 0.0, 0.0], [0.10, 0.07, 0.04]])]
OBJ_IDS = [5, 12]
CENTRES = [np.array([0.0, -0.4, 0.5]), np.array([0.3, -0.3, 0.45]), np.array([-0.2, 0.3, 0.5])]
DEPTH_SCALES = [1.0, 0.1, 1.0]  # image 1 stores depth in 0.1 mm units


def _look_at(c: np.ndarray, target=np.array([0.0, 0.0, 0.02])) -> np.ndarray:
    """T_world_camera with OpenCV axes (z forward, y down) looking from c at target, world z up."""
    z = target - c
    z /= np.linalg.norm(z)
    x = np.cross(np.array([0.0, 0.0, -1.0]), z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    T[:3, 3] = c
    return T


def _object_pose(k: int) -> np.ndarray:
    """A rotated object frame at the box's bottom centre (metadata the loader must carry through)."""
    a = 0.3 + 0.5 * k
    T = np.eye(4)
    T[:3, :3] = [[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]]
    T[:3, 3] = [(BOXES[k][0, 0] + BOXES[k][1, 0]) / 2, (BOXES[k][0, 1] + BOXES[k][1, 1]) / 2, 0.0]
    return T


def _raycast(T_wc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(z-depth (H, W) metres, labels (H, W) int32, -1 = table) for the plane + boxes world."""
    v, u = np.mgrid[0:H, 0:W].astype(np.float64)
    rays_c = np.stack([(u - K[0, 2]) / K[0, 0], (v - K[1, 2]) / K[1, 1], np.ones_like(u)], axis=-1)  # z = 1
    d = rays_c @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    best = -o[2] / d[..., 2]  # ray parameter = z-depth because the camera-frame ray has z = 1
    label = np.full((H, W), -1, np.int32)
    for k, (lo, hi) in enumerate(BOXES):
        with np.errstate(divide="ignore", invalid="ignore"):
            t1, t2 = (lo - o) / d, (hi - o) / d
        tn = np.minimum(t1, t2).max(axis=-1)
        tf = np.maximum(t1, t2).min(axis=-1)
        hit = (tn <= tf) & (tn > 0) & (tn < best)
        best = np.where(hit, tn, best)
        label[hit] = k
    return best, label


def _write_bop_scene(root: Path, *, with_gt: bool = True) -> dict:
    root.mkdir(parents=True)
    cams, gts, truth = {}, {}, {"T_wc": [], "depth": [], "labels": []}
    for im, (c, scale) in enumerate(zip(CENTRES, DEPTH_SCALES)):
        T_wc = _look_at(c)
        T_cw = np.linalg.inv(T_wc)
        depth, labels = _raycast(T_wc)
        truth["T_wc"].append(T_wc)
        truth["depth"].append(depth)
        truth["labels"].append(labels)
        colours = np.array([[200, 200, 200], [255, 0, 0], [0, 0, 255]], np.uint8)
        write_png(root / "rgb" / f"{im:06d}.png", colours[labels + 1])
        write_png(root / "depth" / f"{im:06d}.png", np.round(depth * 1000.0 / scale).astype(np.uint16))
        cams[str(im)] = {
            "cam_K": K.reshape(-1).tolist(),
            "cam_R_w2c": T_cw[:3, :3].reshape(-1).tolist(),
            "cam_t_w2c": (T_cw[:3, 3] * 1000.0).tolist(),
            "depth_scale": scale,
        }
        gts[str(im)] = []
        for k, obj_id in enumerate(OBJ_IDS):
            T_co = T_cw @ _object_pose(k)
            gts[str(im)].append(
                {"obj_id": obj_id, "cam_R_m2c": T_co[:3, :3].reshape(-1).tolist(), "cam_t_m2c": (T_co[:3, 3] * 1000).tolist()}
            )
            write_png(root / "mask_visib" / f"{im:06d}_{k:06d}.png", labels == k)
    (root / "scene_camera.json").write_text(json.dumps(cams))
    if with_gt:
        (root / "scene_gt.json").write_text(json.dumps(gts))
    return truth


@pytest.fixture
def bop(tmp_path: Path) -> tuple[Path, dict]:
    root = tmp_path / "test" / "000003"
    return root, _write_bop_scene(root)


def test_generator_sees_both_boxes_in_every_view(bop):
    _, truth = bop
    for labels in truth["labels"]:
        assert (labels == 0).sum() > 20 and (labels == 1).sum() > 20 and (labels == -1).sum() > 500


def test_poses_are_camera_to_world_in_metres(bop):
    root, truth = bop
    scene = load_bop_scene(root)
    assert [v.frame for v in scene.views] == [0, 1, 2]
    assert scene.initial == (0, 1, 2) and scene.post == ()
    assert scene.name == "000003"
    for v, T_wc, c in zip(scene.views, truth["T_wc"], CENTRES):
        # mm -> m: the camera centre is where the generator put it, in metres
        np.testing.assert_allclose(v.camera.T_world_camera[:3, 3], c, atol=1e-9)
        np.testing.assert_allclose(v.camera.T_world_camera, T_wc, atol=1e-9)
        assert (v.camera.width, v.camera.height) == (W, H)
        np.testing.assert_array_equal(v.camera.K, K)


def test_world_point_projects_where_expected(bop):
    root, truth = bop
    scene = load_bop_scene(root)
    # the top-front corner of box 0 and a table point, projected by hand through the generator's pose
    pts = np.array([[BOXES[0][0, 0], BOXES[0][0, 1], BOXES[0][1, 2]], [0.15, -0.12, 0.0]])
    for v, T_wc in zip(scene.views, truth["T_wc"]):
        pc = (pts - T_wc[:3, 3]) @ T_wc[:3, :3]  # R^T (p - c)
        expect = np.stack([K[0, 0] * pc[:, 0] / pc[:, 2] + K[0, 2], K[1, 1] * pc[:, 1] / pc[:, 2] + K[1, 2]], 1)
        uv, z = v.camera.project(pts)
        np.testing.assert_allclose(uv, expect, atol=1e-6)
        np.testing.assert_allclose(z, pc[:, 2], atol=1e-9)
        assert np.all((uv > 0) & (uv < [W, H]))  # the test points are really inside the image


def test_depth_in_metres_and_depth_scale_honoured(bop):
    root, truth = bop
    scene = load_bop_scene(root)
    for v, depth, scale in zip(scene.views, truth["depth"], DEPTH_SCALES):
        assert v.depth.dtype == np.float32 and np.isfinite(v.depth).all()
        # quantisation of the PNG: half a file unit, i.e. 0.5 mm at scale 1 and 0.05 mm at scale 0.1
        np.testing.assert_allclose(v.depth, depth, atol=scale * 0.5e-3 + 1e-6)
        assert 0.3 < float(np.median(v.depth)) < 1.0
    # image 1's PNG holds 0.1 mm units: read as plain millimetres it would be 10x too deep
    import cv2

    raw = cv2.imread(str(root / "depth" / "000001.png"), cv2.IMREAD_UNCHANGED)
    assert raw.dtype == np.uint16
    np.testing.assert_allclose(scene.views[1].depth, raw * 1e-4, rtol=1e-6)
    assert np.median(raw) * 1e-3 > 3.0


def test_depth_points_land_on_the_surfaces(bop):
    root, _ = bop
    scene = load_bop_scene(root)
    imap = scene.ground_truth.instance_maps
    for v in scene.views:
        p, pix = v.camera.backproject(v.depth)
        lab = imap[v.frame].reshape(-1)[pix]
        table = p[lab == -1]
        assert np.abs(table[:, 2]).max() < 1e-3  # table plane z = 0 (1 mm quantisation)
        for k, (lo, hi) in enumerate(BOXES):
            q = p[lab == k]
            assert len(q) > 0
            assert np.all(q >= lo - 2e-3) and np.all(q <= hi + 2e-3)


def test_instance_maps_match_visible_masks(bop):
    root, truth = bop
    gt = load_bop_scene(root).ground_truth
    assert sorted(gt.instance_maps) == [0, 1, 2]
    for im, labels in enumerate(truth["labels"]):
        m = gt.instance_maps[im]
        assert m.dtype == np.int32 and m.shape == (H, W)
        np.testing.assert_array_equal(m, labels)


def test_objects_poses_and_default_categories(bop):
    root, _ = bop
    gt = load_bop_scene(root).ground_truth
    assert [o.id for o in gt.objects] == [0, 1]
    assert [o.category for o in gt.objects] == ["obj_000005", "obj_000012"]
    assert [o.name for o in gt.objects] == ["obj_000005", "obj_000012"]
    for k, o in enumerate(gt.objects):
        np.testing.assert_allclose(o.T_world_object, _object_pose(k), atol=1e-9)


def test_categories_mapping(bop):
    root, _ = bop
    gt = load_bop_scene(root, categories={5: "mug"}).ground_truth
    assert [o.category for o in gt.objects] == ["mug", "obj_000012"]
    gt = load_bop_scene(root, categories={"12": "banana"}).ground_truth  # keys as read from JSON
    assert [o.category for o in gt.objects] == ["obj_000005", "banana"]
    assert gt.categories == ("banana", "obj_000005")


def test_labelled_points_consistent_with_maps(bop):
    root, _ = bop
    scene = load_bop_scene(root)
    gt = scene.ground_truth
    assert gt.points.dtype == np.float32 and gt.point_labels.dtype == np.int32
    assert set(np.unique(gt.point_labels).tolist()) == {-1, 0, 1}
    n_pixels = sum(int(np.isfinite(v.depth).sum()) for v in scene.views)
    assert 0 < len(gt.points) < n_pixels  # voxel subsampling merged points
    for k, (lo, hi) in enumerate(BOXES):
        q = gt.points[gt.point_labels == k]
        assert len(q) > 10
        assert np.all(q >= lo - 3e-3) and np.all(q <= hi + 3e-3)
    table = gt.points[gt.point_labels == -1]
    assert np.abs(table[:, 2]).max() < 2e-3


def test_frame_selection_initial_and_post(bop):
    root, _ = bop
    scene = load_bop_scene(root, initial=[0, 2], post=[1])
    assert [v.frame for v in scene.views] == [0, 1, 2]
    assert [v.frame for v in scene.initial_views] == [0, 2] and [v.frame for v in scene.post_views] == [1]
    gen = load_bop_scene(root, initial=(f for f in [0, 2]), post=iter([1]))  # one-shot iterators
    assert [v.frame for v in gen.initial_views] == [0, 2] and [v.frame for v in gen.post_views] == [1]
    only = load_bop_scene(root, frames=[2])
    assert [v.frame for v in only.views] == [2] and only.initial == (0,)
    # objects come from the first loaded image; poses are in the world frame, so the same
    np.testing.assert_allclose(only.ground_truth.objects[1].T_world_object, _object_pose(1), atol=1e-9)
    # fewer initial views -> fewer labelled points
    assert len(only.ground_truth.points) < len(load_bop_scene(root).ground_truth.points)


def test_post_frame_without_depth_is_allowed(bop):
    root, _ = bop
    (root / "depth" / "000002.png").unlink()
    scene = load_bop_scene(root, initial=[0, 1], post=[2])
    assert scene.post_views[0].depth is None


def test_no_gt_files_means_no_ground_truth(tmp_path):
    root = tmp_path / "000001"
    _write_bop_scene(root, with_gt=False)
    scene = load_bop_scene(root)
    assert scene.ground_truth is None and all(v.masks is None for v in scene.views)


def test_gt_without_mask_folder_has_objects_but_no_maps(bop):
    root, _ = bop
    for p in (root / "mask_visib").iterdir():
        p.unlink()
    (root / "mask_visib").rmdir()
    gt = load_bop_scene(root).ground_truth
    assert len(gt.objects) == 2 and gt.instance_maps == {} and len(gt.points) == 0


def test_instance_masks_folder_beside_is_loaded(bop):
    root, truth = bop
    for k in range(2):
        write_png(root / "instance_masks" / f"mask_000001_{k + 1:02d}.png", truth["labels"][1] == k)
    scene = load_bop_scene(root)
    v1 = scene.view_by_frame(1)
    assert v1.masks is not None and v1.masks.ids.tolist() == [1, 2]
    np.testing.assert_array_equal(v1.masks.masks[1], truth["labels"][1] == 1)
    assert len(scene.view_by_frame(0).masks) == 0  # folder exists, no candidates for this frame


def test_load_scene_detects_bop(bop):
    root, _ = bop
    assert [v.frame for v in load_scene(root).views] == [0, 1, 2]
    assert len(load_scene(root / "scene_camera.json").views) == 3


def test_overlapping_masks_smaller_wins_then_later():
    big = np.zeros((6, 8), bool)
    big[1:5, 1:7] = True
    small = np.zeros((6, 8), bool)
    small[2:4, 2:4] = True
    m = paint_instances(np.stack([small, big]))  # small first: it must still win its pixels
    assert (m[2:4, 2:4] == 0).all() and (m[big & ~small] == 1).all() and (m[~big] == -1).all()
    a = np.zeros((6, 8), bool)
    a[0:2, 0:2] = True
    b = np.zeros((6, 8), bool)
    b[1:3, 1:3] = True  # same area, overlaps a at (1, 1)
    m = paint_instances(np.stack([a, b]))
    assert m[1, 1] == 1 and m[0, 0] == 0
    assert (paint_instances(np.zeros((0, 3, 4), bool)) == -1).all()


def test_voxel_subsampling_majority_label_and_centroid():
    pts = np.array([[0.0001, 0.0001, 0.0001], [0.0003, 0.0001, 0.0001], [0.0005, 0.0001, 0.0001],
                    [0.0101, 0.0, 0.0]])
    labs = np.array([2, -1, 2, 0])
    p, lab = voxel_labelled_points(pts, labs, 0.002)
    order = np.argsort(p[:, 0])
    np.testing.assert_allclose(p[order], [[0.0003, 0.0001, 0.0001], [0.0101, 0.0, 0.0]], atol=1e-7)
    assert lab[order].tolist() == [2, 0]
    p, lab = voxel_labelled_points(np.zeros((0, 3)), np.zeros(0, int), 0.002)
    assert p.shape == (0, 3) and lab.shape == (0,)



@settings(max_examples=60, deadline=None)
@given(
    hnp.arrays(np.int64, st.tuples(st.integers(1, 40), st.just(3)), elements=st.integers(-6, 6)),
    st.data(),
)
def test_voxel_subsampling_matches_brute_force(cells, data):
    # points at cell centres +- a little, so the voxel of every point is unambiguous
    voxel = 0.002
    jitter = data.draw(hnp.arrays(np.float64, cells.shape, elements=st.floats(-0.4, 0.4)))
    pts = (cells + 0.5 + jitter) * voxel
    labs = data.draw(hnp.arrays(np.int64, len(cells), elements=st.integers(-1, 3)))
    p, lab = voxel_labelled_points(pts, labs, voxel)
    groups: dict[tuple, list[int]] = {}
    for i, c in enumerate(map(tuple, cells)):
        groups.setdefault(c, []).append(i)
    assert len(p) == len(groups)
    got = {tuple(np.floor(q / voxel).astype(int)): (q, l) for q, l in zip(p.astype(np.float64), lab)}
    for c, idx in groups.items():
        q, l = got[c]
        np.testing.assert_allclose(q, pts[idx].mean(axis=0), atol=1e-7)
        values, counts = np.unique(labs[idx], return_counts=True)
        assert l == values[np.argmax(counts)]  # most frequent, smaller label on ties


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(bool, st.tuples(st.integers(0, 5), st.integers(1, 6), st.integers(1, 6))))
def test_paint_instances_picks_smallest_covering_mask(masks):
    m = paint_instances(masks)
    areas = masks.sum(axis=(1, 2))
    covered = masks.any(axis=0)
    assert (m[~covered] == -1).all()
    for v, u in zip(*np.nonzero(covered)):
        cover = np.flatnonzero(masks[:, v, u])
        best = cover[areas[cover] == areas[cover].min()].max()
        assert m[v, u] == best
