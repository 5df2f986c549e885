"""Generator: determinism, shapes and dtypes, ground-truth consistency, round trip through the sample layout."""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.io.sample_layout import load_sample_layout
from clutt3r_core.synth.generator import SynthConfig, generate, load_synth_info, synth_info, write_synth_scene

from .conftest import tiny, tiny_config


def _arrays(res):
    s = res.scene
    out = []
    for v in s.views:
        out += [v.rgb, v.depth, v.masks.masks, v.masks.ids, v.camera.T_world_camera, v.camera.K]
    gt = s.ground_truth
    out += [gt.points, gt.point_labels] + [gt.instance_maps[f] for f in sorted(gt.instance_maps)]
    out += [o.T_world_object for o in gt.objects]
    return out


def test_same_seed_gives_identical_arrays(tiny_scene):
    again = generate(tiny_config(0, depth_noise="none"), progress=False)
    a, b = _arrays(tiny_scene), _arrays(again)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()
    assert [o.name for o in tiny_scene.scene.ground_truth.objects] == [o.name for o in again.scene.ground_truth.objects]


def test_other_seed_differs(tiny_scene):
    other = tiny(5, depth_noise="none")
    assert not np.array_equal(tiny_scene.scene.views[0].rgb, other.scene.views[0].rgb)


def test_shapes_and_dtypes(tiny_scene):
    s = tiny_scene.scene
    assert len(s.views) == 2 and s.initial == (0, 1) and s.post == ()
    for v in s.views:
        assert v.rgb.shape == (120, 160, 3) and v.rgb.dtype == np.uint8
        assert v.depth.shape == (120, 160) and v.depth.dtype == np.float32
        assert v.camera.width == 160 and v.camera.height == 120
        assert v.camera.fx == pytest.approx(100.0)  # 400 px at 640 px width, scaled
        assert v.masks.masks.dtype == bool and v.masks.masks.shape[1:] == (120, 160)
        assert sorted(v.masks.ids.tolist()) == list(range(1, len(v.masks) + 1))
        d = v.depth[np.isfinite(v.depth)]
        assert d.size > 0.9 * v.depth.size and np.allclose(d * 1000, np.round(d * 1000), atol=1e-3)
        # the camera looks at the pile from 0.45-0.75 m
        assert 0.2 < np.nanmin(v.depth) < 0.8
    gt = s.ground_truth
    assert len(gt.objects) == 3
    assert all(o.category and o.T_world_object is not None and o.color is not None for o in gt.objects)
    assert gt.points.dtype == np.float32 and gt.point_labels.dtype == np.int32
    for m in gt.instance_maps.values():
        assert m.dtype == np.int32 and m.shape == (120, 160)


def test_objects_rest_on_table(tiny_scene):
    from clutt3r_core.synth.objects import load_object

    for o in tiny_scene.scene.ground_truth.objects:
        mesh = load_object(o.name)
        T = o.T_world_object
        zmin = (mesh.vertices @ T[:3, :3].T + T[:3, 3])[:, 2].min()
        assert -0.003 < zmin < 0.15


def test_instance_ids_consistent_between_maps_and_points(tiny_scene):
    s = tiny_scene.scene
    gt = s.ground_truth
    ids_maps = set(np.unique(np.concatenate([m.ravel() for m in gt.instance_maps.values()])).tolist())
    ids_pts = set(np.unique(gt.point_labels).tolist())
    assert ids_pts == ids_maps  # the same objects (and background) are seen by maps and points
    assert -1 in ids_pts
    # every labelled point projects, in some view where it is visible, onto a pixel of its label
    for v in s.views:
        uv, z = v.camera.project(gt.points)
        u, vv = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        ok = (z > 0) & (u >= 0) & (u < 160) & (vv >= 0) & (vv < 120)
        d = v.depth[vv[ok], u[ok]]
        seen = np.abs(d - z[ok]) < 0.002  # the point is the visible surface at that pixel
        lab_map = gt.instance_maps[v.frame][vv[ok], u[ok]][seen]
        agree = (lab_map == gt.point_labels[ok][seen]).mean()
        assert agree > 0.97


def test_occlusion_recorded(tiny_scene):
    info = tiny_scene.info
    assert info.occlusion.shape == (3, 2)
    f = info.occlusion[np.isfinite(info.occlusion)]
    assert f.size > 0 and np.all((f >= 0) & (f <= 1))
    assert info.mean_occlusion == pytest.approx(f.mean())
    assert synth_info(tiny_scene.scene) is info


def test_write_and_load_round_trip(tiny_prepost, tmp_path):
    res = tiny_prepost
    out = write_synth_scene(res.scene, tmp_path / "scene")
    assert (out / "contact_sheet.png").is_file()
    back = load_sample_layout(out)
    s = res.scene
    assert back.initial == s.initial and back.post == s.post and back.name == s.name
    for a, b in zip(s.views, back.views):
        assert a.frame == b.frame
        assert np.array_equal(a.rgb, b.rgb)
        assert np.array_equal(a.depth, b.depth, equal_nan=True)
        assert np.array_equal(a.masks.ids, b.masks.ids)
        assert np.array_equal(a.masks.masks, b.masks.masks)
        assert np.allclose(a.camera.T_world_camera, b.camera.T_world_camera)
        assert np.allclose(a.camera.K, b.camera.K)
    ga, gb = s.ground_truth, back.ground_truth
    assert [(o.id, o.category, o.name, o.color) for o in ga.objects] == [(o.id, o.category, o.name, o.color) for o in gb.objects]
    for oa, ob in zip(ga.objects, gb.objects):
        assert np.allclose(oa.T_world_object, ob.T_world_object)
    assert set(ga.instance_maps) == set(gb.instance_maps)
    for f in ga.instance_maps:
        assert np.array_equal(ga.instance_maps[f], gb.instance_maps[f])
    assert np.array_equal(ga.points, gb.points) and np.array_equal(ga.point_labels, gb.point_labels)
    info = load_synth_info(out)
    assert info.interaction is not None
    assert np.allclose(info.interaction.T_new_old, res.info.interaction.T_new_old)
    assert info.mask_kinds[0] == res.info.mask_kinds[0]
    assert info.config == res.info.config


def test_bad_config_is_rejected():
    with pytest.raises(SceneError):
        SynthConfig(preset="extreme")
    with pytest.raises(SceneError):
        SynthConfig(mask_noise="perfect")
    with pytest.raises(SceneError):
        SynthConfig(views=0)
    with pytest.raises(SceneError):
        SynthConfig(objects=("999_nothing",))
