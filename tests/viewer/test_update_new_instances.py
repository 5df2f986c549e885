"""The Updates tab shows the instances an update added (status "new", session 6): they are not in
the run's cloud, so the loader reads their points from the saved state and the tab draws them as a
second point cloud, moved by later updates and gone once removed."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np

from clutt3r_core.update import InstanceUpdate, UpdateResult
from clutt3r_core.update.newobj import next_instance_id
from clutt3r_core.update.state import apply_update, save_state, state_from_segmentation
from clutt3r_core.update.types import NewInstance


def _result(state, frame: int, recs: list, added=()) -> UpdateResult:
    return UpdateResult(frame, tuple(recs), (), np.zeros((len(recs), 4, 4), bool), np.full((4, 4), -1, np.int32), 0.1,
                        added=tuple(added))


def _chain(tiny_seg, run):
    """Update 1 adds instance K (a 2 cm cube of points); update 2 moves it 3 cm along x; update 3
    removes it. Returns (K, its points)."""
    s0 = state_from_segmentation(tiny_seg, run=run)
    k = next_instance_id(s0)
    g = np.arange(0.0, 0.02, 0.005)
    pts = (np.stack(np.meshgrid(g, g, g), -1).reshape(-1, 3) + tiny_seg.points.mean(axis=0)).astype(np.float32)
    static = [InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s0.instance_ids]
    r1 = _result(s0, 8, static + [InstanceUpdate(k, "new", None, 0.9, None, 5, "new-depth")],
                 [NewInstance(k, 5, pts, np.full((len(pts), 3), 200, np.uint8))])
    s1 = apply_update(s0, r1)
    save_state(s1, run / "updates" / "01_frame_000008", r1)
    T = np.eye(4)
    T[0, 3] = 0.03
    r2 = _result(s1, 9, [InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s1.instance_ids if i != k]
                 + [InstanceUpdate(k, "displaced", 0.2, 0.9, T)])
    s2 = apply_update(s1, r2)
    save_state(s2, run / "updates" / "02_frame_000009", r2)
    r3 = _result(s2, 10, [InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s2.instance_ids if i != k]
                 + [InstanceUpdate(k, "removed", None, None, None)])
    save_state(apply_update(s2, r3), run / "updates" / "03_frame_000010", r3)
    return k, pts


def test_added_instances_are_loaded_moved_and_dropped_along_the_chain(tiny_run_dir, tiny_seg, tmp_path):
    import clutt3r_viewer.panels.update_sources  # noqa: F401  (registers the loader)
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.scene_step import scene_after_of, scene_step

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k, pts = _chain(tiny_seg, run)
    d = load_viewer_data(run, images=False)
    assert [u.frame for u in d.updates] == [8, 9, 10]
    assert f"| {k} | new |" in d.updates[0].text
    (a,) = d.updates[0].result.added
    np.testing.assert_allclose(a.points, pts, atol=1e-6)

    def added_points(u: int, after: bool = True):  # the added instances in the tab's scene for (update u, after)
        sa = scene_after_of(d, scene_step(u, after, len(d.updates)))
        return sa.added_points, sa.added_instance

    p, inst = added_points(0)  # after update 1: where it was added
    np.testing.assert_allclose(p, pts, atol=1e-6)
    assert np.all(inst == k)
    assert len(added_points(0, after=False)[0]) == 0  # before update 1: not there yet
    p, _ = added_points(1)  # after update 2: moved 3 cm along x
    np.testing.assert_allclose(p - pts, np.tile([0.03, 0.0, 0.0], (len(pts), 1)), atol=1e-6)
    assert len(added_points(2)[0]) == 0  # after update 3: removed
    np.testing.assert_allclose(added_points(2, after=False)[0], p, atol=1e-9)


def test_scene_panel_draws_the_added_instances(tiny_run_dir, tiny_seg, tmp_path):
    """The Scene panel draws the added instances of the scene shown as a second cloud (session 7:
    in every colour mode, ``clutt3r_viewer.scene_step``), recolours it in place, removes it once
    they are gone."""
    import clutt3r_viewer.panels.update_sources  # noqa: F401
    from clutt3r_viewer.data import label_colors
    from clutt3r_viewer.loading import load_viewer_data
    from clutt3r_viewer.panels.scene import ScenePanel
    from clutt3r_viewer.scene_step import shown_scene

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    k, pts = _chain(tiny_seg, run)
    d = load_viewer_data(run, images=False)
    drawn = []

    class Handle:
        def __init__(self, name, points, colors, position):
            self.args = (name, points, colors, position)
            self.colors = colors
            drawn.append(self)
            self.removed = False

        def remove(self):
            self.removed = True

    scene = SimpleNamespace(add_point_cloud=lambda name, points, colors, position, **kw: Handle(name, points, colors,
                                                                                                  position))
    s = SimpleNamespace(app=SimpleNamespace(data=d, point_size=0.004), client=SimpleNamespace(scene=scene))
    panel = ScenePanel.__new__(ScenePanel)
    panel.cloud = SimpleNamespace(point_size=0.004)
    sc = shown_scene(d, 2, np.arange(len(tiny_seg.points)))  # after update 2: moved 3 cm along x
    panel._draw_added(s, (sc.added_points, sc.added_instance, label_colors(sc.added_instance)))
    (h,) = drawn
    name, p, cols, position = h.args
    assert name == "/cloud_added" and len(p) == len(pts)
    np.testing.assert_allclose(p + np.asarray(position), pts + [0.03, 0.0, 0.0], atol=1e-5)
    grey = np.full((len(pts), 3), 128, np.uint8)
    panel._draw_added(s, (sc.added_points, sc.added_instance, grey))  # same points: colours only
    assert len(drawn) == 1 and h.colors is grey and not h.removed
    s3 = shown_scene(d, 3, np.arange(len(tiny_seg.points)))  # the update that removed it: the cloud goes
    panel._draw_added(s, (s3.added_points, s3.added_instance, label_colors(s3.added_instance)))
    assert h.removed and panel.added is None and len(drawn) == 1
