"""The scene after k updates of a run's chain, as query and grasp see it (issue 10, demo loop).

A robot demo runs segment -> query -> grasp -> ``clutt3r update RUN --frame F`` -> query and
grasp AGAIN. The second query must not rank the grasped (removed) object, the grasp of an
object the robot pushed must be planned where it is now, checked against the cloud as it is
now, and an object the grasp revealed (added, status "new") must be rankable and graspable.

``scene_after(run, step)`` builds that scene from the run folder and its saved chain
(``RUN/updates/*``, ``update.state``): the run's whole fused cloud (rim voxels included, as
``clutt3r grasp`` uses it at step 0) with removed instances' points left out, displaced ones
moved by their composed motions (normals turned with them), plus the added instances' points
(from the state of that step, already moved by later updates) with PCA normals oriented
towards the camera of the update that added them (``eyes``; else towards +z above the
object, the viewer's fallback). Step 0 is the run as segmented, unchanged.

Corrections (session 7): at step > 0 the run's points carry the labelling the chain was
computed from (``state.json`` "labels": the Edit tab's corrections replayed to that log entry,
``update.run_labels``), so the ids agree with update.json; ``stale`` says when corrections made
since then are not in it.

``compose_motions`` is the one place motions of a chain compose (``pose_new = T_world @
pose_old``); the viewer's ``update_motions`` calls it.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Iterable, Mapping

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError, SceneFileError

__all__ = ["SceneAfter", "scene_after", "chain_length", "compose_motions", "resolve_step", "added_masks",
           "oriented_normals", "ADDED_NORMAL_KNN"]

ADDED_NORMAL_KNN = 16
"""ours: neighbours of the PCA normals of added instances (the viewer's Grasps tab uses the same)."""


def _ro(a, dtype) -> np.ndarray:
    a = np.ascontiguousarray(np.asarray(a, dtype))
    a.setflags(write=False)
    return a


def compose_motions(steps: Iterable[Iterable[tuple[int, np.ndarray]]], n_instances: int) -> np.ndarray:
    """(U + 1, I, 4, 4) float64 world motion of every instance id after 0, 1, .., U updates.

    ``steps``: per update, its (instance id, T_world (4, 4)) of displaced instances. A displaced
    instance's motion composes as ``T_world(u) @ motion(u - 1)``; the others keep theirs. I is
    ``n_instances`` or more when a step names a larger id."""
    steps = [[(int(k), np.asarray(T, np.float64)) for k, T in s] for s in steps]
    n = max(int(n_instances), 1 + max((k for s in steps for k, _ in s), default=-1))
    out = np.tile(np.eye(4), (len(steps) + 1, n, 1, 1))
    for u, s in enumerate(steps):
        out[u + 1] = out[u]
        for k, T in s:
            out[u + 1, k] = T @ out[u, k]
    return out


def oriented_normals(points: np.ndarray, eye: np.ndarray | None, knn: int = ADDED_NORMAL_KNN) -> np.ndarray:
    """(P, 3) float64 PCA normals of ``points`` (world metres) turned towards ``eye`` (a camera
    centre, world metres); None: towards a point 1 m above the points' centroid (+z)."""
    from clutt3r_core.normals import estimate_normals

    p = np.asarray(points, np.float64)
    if len(p) == 0:
        return np.zeros((0, 3))
    n = estimate_normals(p, knn) if len(p) >= 3 else np.tile([0.0, 0.0, 1.0], (len(p), 1))
    e = np.asarray(eye, np.float64) if eye is not None else p.mean(axis=0) + [0.0, 0.0, 1.0]
    n[np.einsum("ij,ij->i", n, e - p) < 0] *= -1
    return n


@dataclass(frozen=True, eq=False)
class SceneAfter:
    """A run's scene after its first ``step`` updates.

    Attributes:
        step: updates applied (0 = the run as segmented).
        n_updates: updates in the run's chain.
        frame: post-interaction frame of the last update applied (None at step 0).
        points: (N, 3) float32 world metres: the run's points without removed instances,
            displaced ones moved, then the added instances' points.
        colors: (N, 3) uint8.
        normals: (N, 3) float32 unit, oriented towards the cameras that saw them.
        instance: (N,) int32 instance id of each point, -1 = none.
        present: (K,) int32 instance ids in the scene, ascending.
        removed: {id: (step, frame) of the update that removed it}, for ids removed by ``step``.
        added: {id: (step, frame) of the update that added it}, for added ids still present.
        displaced: ids present that an update of the chain moved, ascending.
        motions: (I, 4, 4) float64 composed world motion of every id of the chain (identity =
            never moved); ``motions[k] @ pose_at_segmentation`` is instance k's pose now.
        run: the run folder (None in memory).
        stale: one line when corrections were made after the chain was computed (its ids are
            the older labelling's; ``update.run_labels.stale_note``), else None.
        run_share: (I0, K) float64 when the chain's ids are a corrected labelling: row i = the
            share of corrected id i's points that each run instance had (rows sum to 1, or 0 for
            an id made only of background points), to carry per-run-instance evidence (query)
            to the corrected ids; None when the ids are the run's.
    """

    step: int
    n_updates: int
    frame: int | None
    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    instance: np.ndarray
    present: np.ndarray
    removed: Mapping[int, tuple[int, int]] = field(default_factory=dict)
    added: Mapping[int, tuple[int, int]] = field(default_factory=dict)
    displaced: tuple[int, ...] = ()
    motions: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    run: Path | None = None
    stale: str | None = None
    run_share: np.ndarray | None = None

    def __post_init__(self) -> None:
        n = len(self.points)
        if np.shape(self.points) != (n, 3) or np.shape(self.colors) != (n, 3) or np.shape(self.normals) != (n, 3) \
                or np.shape(self.instance) != (n,):
            raise SceneError("SceneAfter: points, colors, normals (N, 3) and instance (N,) must agree")
        if not 0 <= self.step <= self.n_updates:
            raise SceneError(f"SceneAfter: step {self.step} outside 0..{self.n_updates}")
        for name, dt in (("points", np.float32), ("colors", np.uint8), ("normals", np.float32),
                         ("instance", np.int32), ("present", np.int32), ("motions", np.float64)):
            object.__setattr__(self, name, _ro(getattr(self, name), dt))
        object.__setattr__(self, "removed", MappingProxyType(dict(self.removed)))
        object.__setattr__(self, "added", MappingProxyType(dict(self.added)))

    @property
    def label(self) -> str:
        """"the run as segmented" or "scene after update 2 (frame 9)" (what the commands print)."""
        return "the run as segmented" if self.step == 0 else f"scene after update {self.step} (frame {self.frame})"

    def has(self, k: int) -> bool:
        return bool(np.isin(int(k), self.present))

    def check_present(self, k: int) -> None:
        """Raise one clear ``SceneError`` when instance ``k`` is not in this scene."""
        k = int(k)
        if self.has(k):
            return
        if k in self.removed:
            s, f = self.removed[k]
            raise SceneError(f"instance {k} was removed by update {s} (frame {f}); it is not in the {self.label} "
                             f"(instances now: {', '.join(map(str, self.present.tolist())) or 'none'})")
        raise SceneError(f"instance {k} does not exist in the {self.label} "
                         f"(instances now: {', '.join(map(str, self.present.tolist())) or 'none'})")

    def points_of(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(P, 3) float32 points and (P, 3) uint8 colours of instance ``k`` here."""
        sel = self.instance == int(k)
        return self.points[sel], self.colors[sel]

    def grasp_request(self, k: int, views=(), voxel_size: float = 0.005):
        """The ``GraspRequest`` for instance ``k``: the whole scene cloud as it is now. At step > 0
        pass no ``views``: the initial depth views no longer show the scene (cloud-only check)."""
        from clutt3r_core.grasping import GraspRequest

        self.check_present(k)
        return GraspRequest(points=self.points, normals=self.normals, target=self.instance == int(k),
                            instance=int(k), views=tuple(views), voxel_size=float(voxel_size))


def chain_length(run_dir: str | Path) -> int:
    from clutt3r_core.update.state import state_dirs

    return len(state_dirs(run_dir))


def resolve_step(run_dir: str | Path, step: int | None) -> int:
    """``step`` checked against the run's chain (None = its latest state); one clear error."""
    n = chain_length(run_dir)
    if step is None:
        return n
    if not 0 <= int(step) <= n:
        raise Clutt3rError(f"{run_dir}: --step {step} does not exist: the run has {n} update(s) "
                           f"(steps 0..{n}; 0 = the run as segmented)")
    return int(step)


def added_masks(run_dir: str | Path, step: int) -> list[tuple[int, int, int]]:
    """(instance id, frame, mask id in that post view) of every instance the first ``step``
    updates added from a mask candidate (``update.json`` "new_masks")."""
    from clutt3r_core.update.state import state_dirs

    out = []
    for d in state_dirs(run_dir)[:step]:
        try:
            doc = json.loads((d / "update.json").read_text())
        except (OSError, json.JSONDecodeError) as e:
            raise SceneFileError(d / "update.json", f"unreadable update ({e})") from None
        for m in doc.get("new_masks", []):
            if m.get("instance") is not None:
                out.append((int(m["instance"]), int(doc["frame"]), int(m["mask"])))
    return out


def scene_after(run_dir: str | Path, step: int | None = None, seg=None,
                eyes: Mapping[int, np.ndarray] | None = None) -> SceneAfter:
    """The scene of run ``run_dir`` after its first ``step`` updates (None: all of them).

    Args:
        seg: the run's ``Segmentation`` when already loaded (else ``runs.load_run``).
        eyes: {frame: camera centre (3,) world metres} of the post views, to orient the added
            instances' normals (``oriented_normals``); missing frames fall back to +z.
    """
    from clutt3r_core.update.state import load_state, state_dirs

    run_dir = Path(run_dir)
    if seg is None:
        from clutt3r_core.runs import load_run

        seg = load_run(run_dir)
    dirs = state_dirs(run_dir)
    step = resolve_step(run_dir, step)
    pts0 = np.asarray(seg.points, np.float64)
    inst0 = np.asarray(seg.instance, np.int32)
    nrm0 = np.asarray(seg.normals, np.float64)
    if step == 0:
        return SceneAfter(0, len(dirs), None, pts0, seg.colors, nrm0, inst0,
                          np.arange(seg.num_instances, dtype=np.int32),
                          motions=np.tile(np.eye(4), (seg.num_instances, 1, 1)), run=run_dir)
    st = load_state(dirs[step - 1])
    hist = st.history[:step]
    if len(hist) != step:
        raise SceneFileError(dirs[step - 1] / "state.json", f"history has {len(hist)} updates, expected {step}")
    from clutt3r_core.update.run_labels import LOG_NAME, run_labels, run_share, stale_note

    stale, share = None, None
    n_run = seg.num_instances
    ids0 = np.arange(n_run)
    if st.labels is not None and st.labels.entries > 0:
        lab = run_labels(run_dir, seg, entries=st.labels.entries)  # the labelling the chain was computed from
        if lab.source.labels_sha256 != st.labels.labels_sha256:
            raise SceneFileError(run_dir / LOG_NAME,
                                 f"replaying its first {st.labels.entries} entries does not give the labels "
                                 f"{dirs[0].name} was computed from (the log was rewritten?)")
        share = run_share(lab.instance, seg.instance, lab.num_ids, seg.num_instances)
        inst0, n_run, ids0 = lab.instance, lab.num_ids, lab.ids
    if (run_dir / LOG_NAME).is_file():  # always there for a corrected chain (run_labels above needs it)
        stale = stale_note(run_dir, seg)
    removed = {k: (h.step, h.frame) for h in hist for k in h.removed}
    added_at = {k: (h.step, h.frame) for h in hist for k in h.added}
    n_ids = max(n_run, 1 + max(added_at, default=-1))
    M = compose_motions([zip(h.displaced, h.T_world) for h in hist], n_ids)[step]
    keep = ~np.isin(inst0, list(removed)) | (inst0 < 0)
    pts, nrm = pts0.copy(), nrm0.copy()
    for k in np.flatnonzero(np.any(M[:n_run] != np.eye(4), axis=(1, 2))):
        sel = inst0 == k
        pts[sel] = pts[sel] @ M[k, :3, :3].T + M[k, :3, 3]
        nrm[sel] = nrm[sel] @ M[k, :3, :3].T
    P, C, N, I = [pts[keep]], [np.asarray(seg.colors)[keep]], [nrm[keep]], [inst0[keep]]
    added = {k: v for k, v in added_at.items() if k not in removed}
    for k in sorted(added):
        sel = st.instance == k
        p = st.points[sel].astype(np.float64)  # the state's: already moved by the later updates
        # orient as seen from the camera that added it, moved like the object since
        eye = None if eyes is None else eyes.get(added[k][1])
        T = M[k]
        if eye is not None:
            eye = T[:3, :3] @ np.asarray(eye, np.float64) + T[:3, 3]
        P.append(p)
        C.append(st.colors[sel])
        N.append(oriented_normals(p, eye))
        I.append(np.full(len(p), k, np.int32))
    present = np.setdiff1d(np.union1d(ids0, list(added)), list(removed)).astype(np.int32)
    moved = sorted({k for h in hist for k in h.displaced} & set(present.tolist()))
    return SceneAfter(step, len(dirs), hist[-1].frame, np.concatenate(P), np.concatenate(C), np.concatenate(N),
                      np.concatenate(I), present, removed, added, tuple(moved), M, run_dir, stale, share)
