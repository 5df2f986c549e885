"""GraspSet files: grasps.npz (the viewer) and grasps.json (the CLI's form), base frame, empty sets."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.errors import SceneFileError
from clutt3r_core.grasping import GraspSet, load_base_frame


def _set(n=3):
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, 3] = np.arange(3 * n).reshape(n, 3) * 0.01
    return GraspSet(T, np.full(n, 0.05, np.float32), np.linspace(1, 0.5, n).astype(np.float32),
                    np.full(n, 2, np.int32), np.zeros((n, 2, 3), np.float32))


def test_json_has_the_issue_form_and_round_trips(tmp_path):
    gs = _set()
    obj = gs.to_json(2, "red mug")
    assert obj["target"] == 2 and obj["query"] == "red mug" and len(obj["grasps"]) == 3
    assert set(obj["grasps"][0]) >= {"T_world_gripper", "width", "score"}
    assert np.asarray(obj["grasps"][0]["T_world_gripper"]).shape == (4, 4)
    json.dumps(obj)  # plain JSON
    p = gs.save_json(tmp_path / "grasps.json", 2, "red mug")
    back = GraspSet.load(p)
    np.testing.assert_allclose(back.poses, gs.poses)
    np.testing.assert_allclose(back.scores, gs.scores)
    assert (back.instance == 2).all()


def test_npz_round_trip(tmp_path):
    gs = _set()
    back = GraspSet.load(gs.save_npz(tmp_path / "grasps.npz"))
    np.testing.assert_allclose(back.poses, gs.poses)
    np.testing.assert_allclose(back.contacts, gs.contacts)


def test_empty_set_is_an_empty_list_with_a_message(tmp_path):
    gs = GraspSet.empty(4, "no grasp: too big")
    obj = gs.to_json(4)
    assert obj["grasps"] == [] and obj["target"] == 4 and obj["query"] is None and "too big" in obj["message"]
    assert len(GraspSet.load(gs.save_npz(tmp_path / "g.npz"))) == 0
    assert len(GraspSet.load(gs.save_json(tmp_path / "g.json", 4))) == 0


def test_base_frame(tmp_path):
    Tb = np.eye(4)
    Tb[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    Tb[:3, 3] = [0.5, 0, -0.1]
    (tmp_path / "b.json").write_text(json.dumps({"T_base_world": Tb.tolist()}))
    np.savetxt(tmp_path / "b.txt", Tb)
    for f in ("b.json", "b.txt"):
        np.testing.assert_allclose(load_base_frame(tmp_path / f), Tb)
    gs = _set()
    obj = gs.to_json(2, None, Tb)
    np.testing.assert_allclose(obj["grasps"][1]["T_base_gripper"], Tb @ gs.poses[1])
    np.testing.assert_allclose(obj["grasps"][1]["T_world_gripper"], gs.poses[1])


def test_bad_files_name_the_file(tmp_path):
    (tmp_path / "b.json").write_text(json.dumps([[1, 0], [0, 1]]))
    with pytest.raises(SceneFileError, match="b.json"):
        load_base_frame(tmp_path / "b.json")
    (tmp_path / "s.json").write_text(json.dumps(2 * np.eye(4).tolist()))
    with pytest.raises(SceneFileError, match="s.json"):
        load_base_frame(tmp_path / "s.json")
    (tmp_path / "g.json").write_text('{"target": 1}')
    with pytest.raises(SceneFileError, match="g.json"):
        GraspSet.load(tmp_path / "g.json")
