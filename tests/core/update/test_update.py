"""Scene update end to end on tiny synthetic scenes: association, change detection, pose,
the new state and its chain, update.json, and the CLI with an outside image."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from clutt3r_core.embeddings import AppearanceEmbedder
from clutt3r_core.io.images import write_png
from clutt3r_core.scene import MaskCandidates, View
from clutt3r_core.update.state import (
    SceneState,
    apply_update,
    latest_state,
    load_pose_traces,
    load_state,
    save_state,
)
from clutt3r_core.update.types import PoseConfig, StageConfig, UpdateConfig
from clutt3r_core.update.update import UpdateDetails, update_scene

from ._scenes import camera, render_view, two_box_scene, yaw_motion

FAST = UpdateConfig(pose=PoseConfig(coarse=StageConfig(50.0, 0.5, 10.0, 40), fine=StageConfig(10.0, 2.0, 1.0, 20),
                                    yaw_starts_deg=(0.0, 40.0), probe_iterations=8, dof="yaw"))
PAPER = replace(FAST, change=replace(FAST.change, use_depth=False))
NEW_CAM = dict(eye=(0.12, -0.42, 0.42))  # the post view is not one of the initial views


def _state() -> SceneState:
    pts, cols, inst = two_box_scene()
    v = render_view(pts, cols, inst, camera(), frame=0)
    emb = AppearanceEmbedder().embed_masks(v.rgb, v.masks.masks)  # rows: ids 1, 2 = instances 0, 1
    return SceneState(pts, cols, inst, np.array([0, 1], np.int32), emb, "appearance-hsv")


def _post(T0: np.ndarray | None = None, remove: int | None = None, depth: bool = True, frame: int = 8) -> View:
    pts, cols, inst = two_box_scene()
    pts = pts.copy()
    if T0 is not None:
        pts[inst == 0] = pts[inst == 0] @ T0[:3, :3].T + T0[:3, 3]
    keep = inst != remove if remove is not None else np.ones(len(inst), bool)
    return render_view(pts[keep], cols[keep], inst[keep], camera(**NEW_CAM), frame=frame, with_depth=depth)


def test_unchanged_scene_flags_nothing():
    st = _state()
    for depth in (True, False):
        res = update_scene(st, _post(depth=depth), FAST)
        assert [r.status for r in res.instances] == ["static", "static"]
        assert all(r.iou_before >= 0.75 and r.T_world is None for r in res.instances)
        assert res.new_masks == ()
        nxt = apply_update(st, res)
        np.testing.assert_array_equal(nxt.points, st.points)


@pytest.mark.parametrize("depth", [True, False])
def test_removed_object_is_reported(depth):
    st = _state()
    res = update_scene(st, _post(remove=1, depth=depth), FAST)
    assert res.record(1).status == "removed" and res.record(1).T_world is None
    assert res.record(0).status == "static"
    nxt = apply_update(st, res)
    assert nxt.instance_ids.tolist() == [0] and not np.any(nxt.instance == 1)
    assert nxt.history[-1].removed == (1,)


def test_displaced_object_is_moved_and_the_update_chains(tmp_path):
    st = _state()
    c = st.points_of(0).astype(np.float64).mean(axis=0)
    T = yaw_motion(25.0, (0.0, -0.05, 0.0), c)
    details = UpdateDetails()
    # the paper's path (no depth cues: test_depth.py covers those): found by embedding
    res = update_scene(st, _post(T0=T), PAPER, details=details)
    r0 = res.record(0)
    assert r0.status == "displaced" and r0.match == "semantic"  # its projection moved away: found by embedding
    assert res.record(1).status == "static"
    moved = r0.T_world[:3, :3] @ c + r0.T_world[:3, 3]
    assert np.linalg.norm(moved - (T[:3, :3] @ c + T[:3, 3])) < 0.01
    assert r0.iou_after > 0.85 > r0.iou_before
    assert details.association.s_semantic.shape == (2, 2)
    # state 1, saved and read back
    s1 = apply_update(st, res)
    d1 = save_state(s1, tmp_path / "updates" / "01_frame_000008", res)
    back = load_state(d1)
    np.testing.assert_array_equal(back.points, s1.points)
    assert back.step == 1 and back.history[0].displaced == (0,)
    traces = load_pose_traces(d1)
    assert len(traces[0]) == len(r0.pose.trace)
    doc = json.loads((d1 / "update.json").read_text())
    assert set(doc) == {"frame", "instances", "new_masks", "time_s", "embedder", "camera"}
    assert doc["embedder"] == "appearance-hsv" and doc["camera"] == camera(**NEW_CAM).to_json()  # the post view's
    assert set(doc["instances"][0]) == {"instance", "status", "iou_before", "iou_after", "T_world"}
    assert doc["instances"][1]["T_world"] is None and np.asarray(doc["instances"][0]["T_world"]).shape == (4, 4)
    # update 2 from state 1: the same view again changes nothing; then object 1 is grasped
    res2 = update_scene(back, _post(T0=T, frame=9), PAPER)
    assert [r.status for r in res2.instances] == ["static", "static"]
    res3 = update_scene(back, _post(T0=T, remove=1, frame=9), PAPER)
    assert res3.record(1).status == "removed" and res3.record(0).status == "static"
    s2 = apply_update(back, res3)
    save_state(s2, tmp_path / "updates" / "02_frame_000009", res3)
    last, folder = latest_state(tmp_path)
    assert folder.name == "02_frame_000009" and last.step == 2
    assert [h.frame for h in last.history] == [8, 9] and last.instance_ids.tolist() == [0]


def test_cli_with_an_outside_image(tmp_path):
    from clutt3r_core.commands.update import update_command

    st = _state()
    start = save_state(st, tmp_path / "start")
    view = _post(remove=1, depth=False)
    write_png(tmp_path / "post.png", view.rgb)
    (tmp_path / "masks").mkdir()
    for m, i in zip(view.masks.masks, view.masks.ids):
        write_png(tmp_path / "masks" / f"mask_000008_{i:02d}.png", m.astype(np.uint8) * 255)
    cam = view.camera
    (tmp_path / "cam.json").write_text(json.dumps({"K": cam.K.tolist(), "width": cam.width, "height": cam.height,
                                                   "T_world_camera": cam.T_world_camera.tolist()}))
    out = tmp_path / "out"
    update_command(start, image=tmp_path / "post.png", masks=tmp_path / "masks", camera=tmp_path / "cam.json",
                   out=out, config=FAST)
    doc = json.loads((out / "update.json").read_text())
    assert [(d["instance"], d["status"]) for d in doc["instances"]] == [(0, "static"), (1, "removed")]
    assert (out / "overlay.png").is_file() and load_state(out).instance_ids.tolist() == [0]


def test_view_without_masks_is_refused():
    st = _state()
    v = _post()
    bare = View(v.frame, v.rgb, v.camera, v.depth, None)
    with pytest.raises(Exception, match="no mask candidates"):
        update_scene(st, bare, FAST)
    empty = View(v.frame, v.rgb, v.camera, v.depth, MaskCandidates.empty(v.camera.height, v.camera.width))
    res = update_scene(st, empty, FAST)  # nothing detected: every visible object is checked by depth
    assert [r.status for r in res.instances] == ["static", "static"]


def test_lazy_mask_embeddings_match_the_eager_ones_and_skip_spatial_matches():
    from clutt3r_core.update.associate import associate, project_instances
    from clutt3r_core.update.types import AssociationConfig

    st = _state()
    c = st.points_of(0).astype(np.float64).mean(axis=0)
    view = _post(T0=yaw_motion(25.0, (0.0, -0.05, 0.0), c))
    proj = project_instances(st.points, st.instance, st.instance_ids, view.camera, 0.005, colors=st.colors)
    emb = AppearanceEmbedder()
    eager = associate(view, proj, st.embeddings, emb.embed_masks(view.rgb, view.masks.masks), AssociationConfig(tau_sem=0.65))
    asked = []

    def lazy_fn(idx):
        asked.extend(idx.tolist())
        return emb.embed_masks(view.rgb, view.masks.masks[idx])

    lazy = associate(view, proj, st.embeddings, lazy_fn, AssociationConfig(tau_sem=0.65))
    assert lazy.mask_index.tolist() == eager.mask_index.tolist() and lazy.match == eager.match
    spatial = {int(m) for m, how in zip(lazy.mask_index, lazy.match) if how == "spatial"}
    assert spatial and not spatial & set(asked)  # the static box's mask was never embedded
    assert np.all(np.isnan(lazy.s_semantic[sorted(spatial)]))


@pytest.mark.parametrize(
    "kw, field",
    [({"tau_iou": 75.0}, "tau_iou"), ({"max_fit_overlap": -0.1}, "max_fit_overlap"),
     ({"photo_fragment_points": -1}, "photo_fragment_points"), ({"splat_scale": 0.0}, "splat_scale"),
     ({"photo_gone_fraction": 0.8}, "photo_gone_fraction")],
)
def test_change_config_rejects_out_of_range_values_naming_the_field(kw, field):
    """A mistyped change-detection threshold (70 for 0.7, a negative size) fails at construction
    with the field's name, instead of silently flagging or keeping every instance."""
    from clutt3r_core.errors import SceneError
    from clutt3r_core.update.types import ChangeConfig

    with pytest.raises(SceneError, match=field):
        ChangeConfig(**kw)
    ChangeConfig()  # the defaults themselves are valid
