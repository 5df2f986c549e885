"""A run with a chain of three updates that exercises every kind of change, built through the
core's API (``apply_update`` / ``save_state``) on the tiny viewer scene:

1. frame 8: instance 0 pushed ``SHIFT_0`` along +x (a recorded pose optimisation), instance 2
   removed (grasped), a new instance K added (the surface of a 3 cm cube, ``NEW_OFFSET``
   above the cloud's centre; the object the grasp revealed);
2. frame 9: the added instance K pushed ``SHIFT_K`` along +x (recorded pose optimisation);
3. frame 10: K removed.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from clutt3r_core.update import InstanceUpdate, PoseResult, PoseTrace, UpdateResult
from clutt3r_core.update.newobj import next_instance_id
from clutt3r_core.update.state import apply_update, save_state, state_from_segmentation
from clutt3r_core.update.types import NewInstance, NewMask

SHIFT_0 = 0.05
SHIFT_K = 0.03
NEW_OFFSET = np.array([0.0, 0.0, 0.08])
N_ITER = (6, 4)


def _moved(k: int, shift: float, n_iter: int) -> InstanceUpdate:
    Ts = np.tile(np.eye(4), (n_iter, 1, 1))
    Ts[:, 0, 3] = np.linspace(0.0, shift, n_iter)
    trace = PoseTrace(np.zeros(n_iter, np.int8), Ts, np.tile(np.linspace(1, 0.1, n_iter)[:, None], (1, 5)),
                      np.linspace(0.1, 0.9, n_iter))
    return InstanceUpdate(k, "displaced", 0.1, 0.9, Ts[-1], pose=PoseResult(Ts[-1], 0.1, 0.9, trace, 1, 0.0))


def _result(frame: int, recs: list, added=(), new_masks=()) -> UpdateResult:
    return UpdateResult(frame, tuple(recs), tuple(new_masks), np.zeros((len(recs), 4, 4), bool),
                        np.full((4, 4), -1, np.int32), 0.1,
                        added=tuple(added))


def new_points(seg) -> np.ndarray:
    """The added object's points: the surface of a 3 cm cube, 2.5 mm apart."""
    g = np.arange(13) * 0.0025
    a, b = (x.ravel() for x in np.meshgrid(g, g, indexing="ij"))
    z, e = np.zeros_like(a), np.full_like(a, g[-1])
    faces = [np.stack(f, 1) for f in ((a, b, z), (a, b, e), (a, z, b), (a, e, b), (z, a, b), (e, a, b))]
    cube = np.unique(np.round(np.concatenate(faces), 6), axis=0)
    centre = (seg.points.min(axis=0) + seg.points.max(axis=0)) / 2
    return (cube - cube.mean(axis=0) + centre + NEW_OFFSET).astype(np.float32)


NEW_RGB = (250, 40, 200)


def build_chain(seg, run: Path, embedding: np.ndarray | None = None, frame: int = 8, mask: int = 5) -> int:
    """Write the three updates under ``run/updates``; returns K, the added instance's id.
    ``embedding``: the added instance's (its mask's) embedding, default a unit axis; ``frame``
    and ``mask``: update 1's frame and the added instance's mask candidate in it (default: a
    frame the scene does not have)."""
    s0 = state_from_segmentation(seg, run=run)
    k = next_instance_id(s0)
    pts = new_points(seg)
    emb = np.zeros(s0.embeddings.shape[1], np.float32)
    emb[0] = 1.0
    if embedding is not None:
        emb = np.asarray(embedding, np.float32) / np.linalg.norm(embedding)
    recs = [_moved(0, SHIFT_0, N_ITER[0]) if i == 0 else InstanceUpdate(int(i), "removed" if i == 2 else "static",
                                                                            None if i == 2 else 0.9,
                                                                            None if i == 2 else 0.9, None)
            for i in s0.instance_ids]
    r1 = _result(frame, recs + [InstanceUpdate(k, "new", None, 0.9, None, mask, "new-depth")],
                 [NewInstance(k, mask, pts, np.tile(np.array(NEW_RGB, np.uint8), (len(pts), 1)), emb)],
                 (NewMask(mask, 100, k),))
    s1 = apply_update(s0, r1)
    save_state(s1, run / "updates" / f"01_frame_{frame:06d}", r1)
    r2 = _result(9, [InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s1.instance_ids if i != k]
                 + [_moved(k, SHIFT_K, N_ITER[1])])
    s2 = apply_update(s1, r2)
    save_state(s2, run / "updates" / "02_frame_000009", r2)
    r3 = _result(10, [InstanceUpdate(int(i), "static", 0.9, 0.9, None) for i in s2.instance_ids if i != k]
                 + [InstanceUpdate(k, "removed", None, None, None)])
    save_state(apply_update(s2, r3), run / "updates" / "03_frame_000010", r3)
    return k


def fake_query_panel(d, monkeypatch, step: int = 1):
    """A Query panel over viewer data ``d`` showing the scene after ``step`` updates, with the
    fake language backend (tests.core.query._fake): (panel, session stand-in, its state)."""
    import threading
    from types import SimpleNamespace

    import clutt3r_core.query as cq
    import clutt3r_viewer.panels.query as qp
    from clutt3r_viewer.scene_step import shown_scene
    from tests.core.query._fake import FakeGrounder

    monkeypatch.setattr(qp, "language_backend_name", lambda: "fake-ground")
    monkeypatch.setattr(cq, "create_grounder", lambda name=None: FakeGrounder())
    state = SimpleNamespace(query="", query_best=-1, query_scores=None, color_mode="instance")
    s = SimpleNamespace(app=SimpleNamespace(text_embedder=None, data=d), lock=threading.Lock(), state=state,
                        changed=lambda c: None, scene_step=lambda: step,
                        scene=lambda: shown_scene(d, step, np.arange(len(d.seg.points))))
    panel = qp.QueryPanel()
    panel.result = SimpleNamespace(content="")
    return panel, s, state
