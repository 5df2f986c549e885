"""Physics piles: settled, resting on the table or tray floor, deterministic."""

from __future__ import annotations

import numpy as np

from clutt3r_core.synth.objects import load_object
from clutt3r_core.synth.physics import TraySpec, settle_pile


def _lowest(objs, poses):
    return np.array([(o.vertices @ T[:3, :3].T + T[:3, 3])[:, 2].min() for o, T in zip(objs, poses)])


def test_pile_settles_on_table_and_is_deterministic():
    objs = [load_object(k) for k in ("013_apple", "005_tomato_soup_can", "009_gelatin_box", "011_banana")]
    a = settle_pile(objs, np.random.default_rng(3), pile_radius=0.08)
    b = settle_pile(objs, np.random.default_rng(3), pile_radius=0.08)
    assert np.array_equal(a.poses, b.poses)
    assert a.settled and a.kept.all()
    low = _lowest(objs, a.poses)
    assert low.min() > -0.003 and np.sort(low)[0] < 0.003  # something touches the table
    for T in a.poses:
        R = T[:3, :3]
        assert np.allclose(R.T @ R, np.eye(3), atol=1e-6)


def test_tray_keeps_objects_above_its_floor():
    tray = TraySpec()
    objs = [load_object(k) for k in ("017_orange", "026_sponge", "010_potted_meat_can")]
    p = settle_pile(objs, np.random.default_rng(0), pile_radius=0.06, tray=tray)
    assert p.kept.all()
    assert _lowest(objs, p.poses).min() > tray.floor_thickness - 0.003
