"""The scene after k updates of a run's chain, as query and grasp see it (issue 10, demo loop).

A robot demo runs segment -> query -> grasp -> ``clutt3r update RUN --frame F`` -> query and
grasp AGAIN. The second query must not rank the grasped (removed) object, the grasp of an
object the robot pushed must be planned where it is now, checked against the cloud as it is
now, and an object the grasp revealed (added, status "new") must be rankable and graspable.

``build_scene_after(ChainInputs)`` builds that scene, a pure function over what it is made
from; ``chain_inputs(run, step)`` reads those inputs from the run folder and its saved chain
(``RUN/updates/*``, ``update.state``), ``scene_after`` is the two, and the viewer fills the same
inputs from the chain it loaded (``clutt3r_viewer.scene_step.chain_inputs_of``), so the scene a
tab shows is the one the commands see. It is the run's whole fused cloud (rim voxels included, as
``clutt3r grasp`` uses it at step 0) with removed instances' points left out, displaced ones
moved by their composed motions (normals turned with them), plus the added instances' points
(from the state of that step, already moved by later updates) with PCA normals oriented
towards the camera of the update that added them (``eyes``; else towards +z above the
object, the viewer's fallback). Step 0 is the run as segmented, unchanged.

Corrections (session 7): at step > 0 the run's points carry the labelling the chain was
computed from (``state.json`` "labels": the Edit tab's corrections replayed to that log entry,
``update.run_labels``), so the ids agree with update.json; ``stale`` says when corrections made
since then are not in it.

Two labellings of the run's points (session 9): ``instance`` is the chain's labelling as the Edit
tab shows it (after the object-support contact rule, ``refine.contact_labels``: on noisy depth
each object's lowest ~2 mm unlabelled; and the weak-echo rule when on); ``geometry`` is the same
ids BEFORE those rules, with the contact fill's points (``geometry.geometry_labels``), what the
update's state holds (``state._geometry_labels``). Every
consumer of an object's whole extent reads ``geometry``: which points an update moves with their
instance and leaves out with a removed one (as the state moved and dropped them), and the grasp
target (``SceneAfter.grasp_request``, as at step 0: ``run_labels.StepZeroLabels.geometry``).
Before, the target after an update lost its lowest millimetres (98 points on sample_seq4) and
a displaced object's contact points stayed where it was (a ghost strip in the collision cloud).

``compose_motions`` is the one place motions of a chain compose (``pose_new = T_world @
pose_old``).

Reading the chain's files (steps, update.json, post cameras) is ``update.chain_files``; which
geometry a saved state holds is ``update.geometry.held_geometry``. Both modules' names used by
the commands and the viewer stay importable from here.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from types import MappingProxyType
from typing import Iterable, Mapping

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
# reading the chain's files (steps, update.json, post cameras) lives in ``update.chain_files``; its
# names stay importable from here, where the commands, the query and the viewer import them
from clutt3r_core.update.chain_files import (added_masks, chain_length, post_camera, post_cameras, post_eyes,
                                             resolve_step, update_docs)
from clutt3r_core.update.geometry import geometry_labels, held_geometry, run_geometry, state_rows

__all__ = ["SceneAfter", "ChainInputs", "build_scene_after", "chain_inputs", "scene_after", "chain_length",
           "compose_motions", "resolve_step", "update_docs", "added_masks", "post_camera",
           "post_cameras", "post_eyes", "held_geometry", "state_rows", "oriented_normals", "ADDED_NORMAL_KNN"]

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
class ChainInputs:
    """What the scene after a chain's first ``len(history)`` updates is built from
    (``build_scene_after``, pure). ``chain_inputs`` reads it from a run folder; the viewer fills
    it from the chain it loaded (``clutt3r_viewer.scene_step``), so both show one scene.

    Attributes:
        points: (N, 3) float32 world metres, the run's whole fused cloud (rim voxels included).
        colors: (N, 3) uint8.
        normals: (N, 3) float32 unit.
        instance: (N,) int32 the chain's labelling of those points (the corrected ids when the
            chain was computed after corrections, ``update.run_labels``), -1 = none.
        ids: (K,) int32 the instances of that labelling before any update, ascending.
        num_ids: ids the labelling ever used (the motions cover at least these).
        history: the updates applied, in chain order (``state.HistoryEntry``; () = step 0).
        n_updates: updates in the whole chain (>= len(history)).
        added_points: (A, 3) float32 world metres: the points of the instances the updates added
            and did not remove, as the state after them holds them (moved by the later updates).
        added_colors: (A, 3) uint8.
        added_instance: (A,) int32 their ids.
        eyes: {frame: (3,) camera centre of that post view, world metres}, to orient the added
            instances' normals; a frame without one orients them towards +z.
        run, stale, run_share: carried into ``SceneAfter`` as they are (the viewer leaves
            run_share None: no tab reads it from the scene; its Query tab mixes the evidence
            once per chain, ``clutt3r_viewer.panels.query.added_instance_evidence``).
        geometry: (N,) int32 the same ids before the contact rule (``geometry.geometry_labels``;
            the update state's labels of these points): the points each update moved and removed with their
            instance, and the grasp target's. None, or labels equal to ``instance`` (clean depth,
            the paper preset): ``instance`` itself (a run without the rule, and chains whose state
            holds other labels, ``chain_inputs``).
        source: the labelling the chain was computed from (``state.json`` "labels",
            ``run_labels.LabelSource``; None: not recorded, and in the viewer's scenes), carried
            into ``SceneAfter``.
        corrected_away: {id: why it is no instance} of the ids that labelling's corrections merged,
            deleted or emptied (``run_labels.RunLabels.gone``), carried into ``SceneAfter``.
    """

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    instance: np.ndarray
    ids: np.ndarray
    num_ids: int
    history: tuple = ()
    n_updates: int = 0
    added_points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    added_colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    added_instance: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int32))
    eyes: Mapping[int, np.ndarray] = field(default_factory=dict)
    run: Path | None = None
    stale: str | None = None
    run_share: np.ndarray | None = None
    geometry: np.ndarray | None = None
    source: object | None = None
    corrected_away: Mapping[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n, a = len(self.points), len(self.added_points)
        if np.shape(self.points) != (n, 3) or np.shape(self.colors) != (n, 3) or np.shape(self.normals) != (n, 3) \
                or np.shape(self.instance) != (n,) or np.shape(self.instance if self.geometry is None
                                                             else self.geometry) != (n,):
            raise SceneError("ChainInputs: points, colors, normals (N, 3), instance and geometry (N,) must agree")
        if np.shape(self.added_points) != (a, 3) or np.shape(self.added_colors) != (a, 3) \
                or np.shape(self.added_instance) != (a,):
            raise SceneError("ChainInputs: added_points, added_colors (A, 3) and added_instance (A,) must agree")
        if len(self.history) > self.n_updates:
            raise SceneError(f"ChainInputs: {len(self.history)} updates applied of a chain of {self.n_updates}")
        for name, dt in (("points", np.float32), ("colors", np.uint8), ("normals", np.float32),
                         ("instance", np.int32), ("ids", np.int32), ("added_points", np.float32),
                         ("added_colors", np.uint8), ("added_instance", np.int32)):
            object.__setattr__(self, name, _ro(getattr(self, name), dt))
        # None or equal: the same array object as ``instance`` (``build_scene_after`` then skips the second labelling)
        geo = self.geometry
        object.__setattr__(self, "geometry", self.instance if geo is None or np.array_equal(geo, self.instance)
                           else _ro(geo, np.int32))
        object.__setattr__(self, "history", tuple(self.history))
        object.__setattr__(self, "corrected_away", MappingProxyType(dict(self.corrected_away)))
        object.__setattr__(self, "eyes", MappingProxyType({int(f): np.asarray(e, np.float64)
                                                           for f, e in dict(self.eyes).items()}))


@dataclass(frozen=True, eq=False)
class SceneAfter:
    """A run's scene after its first ``step`` updates (``build_scene_after``).

    The run's points are kept whole (``run_*``, N rows: the viewer draws the removed ones as
    ghosts where they were last seen); ``points`` / ``colors`` / ``normals`` / ``instance`` are
    the scene itself: the run's points of instances not removed, then the added instances'.

    Attributes:
        step: updates applied (0 = the run as segmented).
        n_updates: updates in the run's chain.
        frame: post-interaction frame of the last update applied (None at step 0).
        run_points: (N, 3) float32 world metres, every run point: displaced instances moved by
            their composed motions, removed ones where they were last seen.
        run_colors: (N, 3) uint8.
        run_normals: (N, 3) float32 unit, turned with their instance.
        run_instance: (N,) int32 the chain's id of each run point (the chain's labelling, as the
            Edit tab shows it; a removed instance's points keep its id: they are ``gone``), -1 = none.
        gone: (N,) bool run points of instances removed by ``step`` (by ``run_geometry``: the
            removed instance's contact points go with it, as the update's state dropped them).
        added_points: (A, 3) float32 world metres, the added instances' points now.
        added_colors: (A, 3) uint8.
        added_normals: (A, 3) float32 unit PCA normals, oriented towards the camera of the
            update that added them, moved like the instance since (``oriented_normals``).
        added_instance: (A,) int32 their ids.
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
            to the corrected ids; None when the ids are the run's (and in the viewer's scenes,
            ``ChainInputs``).
        run_geometry: (N,) int32 the chain's ids before the contact rule (``ChainInputs.geometry``):
            ``run_points`` moved and ``gone`` by it; None: ``run_instance``.
        source: the labelling the chain was computed from (``run_labels.LabelSource``, state.json
            "labels"), None when not recorded; ``corrections`` is what grasps.json records of it.
        corrected_away: {id: why it is no instance} of the ids that labelling's corrections merged,
            deleted or emptied (``ChainInputs.corrected_away``): ``check_present`` names the id a
            merged one joined, as at step 0.
    """

    step: int
    n_updates: int
    frame: int | None
    run_points: np.ndarray
    run_colors: np.ndarray
    run_normals: np.ndarray
    run_instance: np.ndarray
    gone: np.ndarray
    added_points: np.ndarray
    added_colors: np.ndarray
    added_normals: np.ndarray
    added_instance: np.ndarray
    present: np.ndarray
    removed: Mapping[int, tuple[int, int]] = field(default_factory=dict)
    added: Mapping[int, tuple[int, int]] = field(default_factory=dict)
    displaced: tuple[int, ...] = ()
    motions: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    run: Path | None = None
    stale: str | None = None
    run_share: np.ndarray | None = None
    run_geometry: np.ndarray | None = None
    source: object | None = None
    corrected_away: Mapping[int, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        n, a = len(self.run_points), len(self.added_points)
        if self.run_geometry is not None and np.shape(self.run_geometry) != (n,):
            raise SceneError("SceneAfter: run_geometry must be (N,) as run_points")
        if any(np.shape(getattr(self, x)) != (n, 3) for x in ("run_points", "run_colors", "run_normals")) \
                or np.shape(self.run_instance) != (n,) or np.shape(self.gone) != (n,):
            raise SceneError("SceneAfter: run_points, run_colors, run_normals (N, 3), run_instance and gone (N,) "
                             "must agree")
        if any(np.shape(getattr(self, x)) != (a, 3) for x in ("added_points", "added_colors", "added_normals")) \
                or np.shape(self.added_instance) != (a,):
            raise SceneError("SceneAfter: added_points, added_colors, added_normals (A, 3) and added_instance (A,) "
                             "must agree")
        if not 0 <= self.step <= self.n_updates:
            raise SceneError(f"SceneAfter: step {self.step} outside 0..{self.n_updates}")
        for name, dt in (("run_points", np.float32), ("run_colors", np.uint8), ("run_normals", np.float32),
                         ("run_instance", np.int32), ("gone", np.bool_), ("added_points", np.float32),
                         ("added_colors", np.uint8), ("added_normals", np.float32), ("added_instance", np.int32),
                         ("present", np.int32), ("motions", np.float64)):
            object.__setattr__(self, name, _ro(getattr(self, name), dt))
        object.__setattr__(self, "run_geometry", self.run_instance if self.run_geometry is None
                           else _ro(self.run_geometry, np.int32))
        object.__setattr__(self, "removed", MappingProxyType(dict(self.removed)))
        object.__setattr__(self, "added", MappingProxyType(dict(self.added)))
        object.__setattr__(self, "corrected_away", MappingProxyType(dict(self.corrected_away)))

    def _scene(self, run: np.ndarray, added: np.ndarray) -> np.ndarray:
        if not self.gone.any() and not len(added):
            return run  # step 0 and chains that removed and added nothing: no copy
        out = np.concatenate([run[~self.gone], added])
        out.setflags(write=False)
        return out

    @cached_property
    def points(self) -> np.ndarray:
        """(P, 3) float32 world metres: the run's points without removed instances, then the added ones."""
        return self._scene(self.run_points, self.added_points)

    @cached_property
    def colors(self) -> np.ndarray:
        """(P, 3) uint8, rows as ``points``."""
        return self._scene(self.run_colors, self.added_colors)

    @cached_property
    def normals(self) -> np.ndarray:
        """(P, 3) float32 unit, oriented towards the cameras that saw them; rows as ``points``."""
        return self._scene(self.run_normals, self.added_normals)

    @cached_property
    def instance(self) -> np.ndarray:
        """(P,) int32 instance id of each point of ``points``, -1 = none."""
        return self._scene(self.run_instance, self.added_instance)

    @cached_property
    def geometry(self) -> np.ndarray:
        """(P,) int32 instance id of each point of ``points`` before the contact rule (``run_geometry``,
        then the added instances' ids), -1 = none: an object's whole extent (the grasp target)."""
        return self._scene(self.run_geometry, self.added_instance)

    @property
    def corrections(self) -> dict | None:
        """``LabelSource.record`` of the correction log state the chain's ids came from (what
        grasps.json records as "corrections", as at step 0: ``StepZeroLabels.to_json``); None when
        the chain was computed from the run as segmented (no log entries) or does not record it."""
        return None if self.source is None else self.source.record()

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
        if k in self.corrected_away:  # as at step 0 (``StepZeroLabels.check_target``): name the id it joined
            raise SceneError(f"instance {k} is not in the {self.label}: before the chain's updates, "
                             f"{self.corrected_away[k]} (instances now: "
                             f"{', '.join(map(str, self.present.tolist())) or 'none'})")
        raise SceneError(f"instance {k} does not exist in the {self.label} "
                         f"(instances now: {', '.join(map(str, self.present.tolist())) or 'none'})")

    def points_of(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(P, 3) float32 points and (P, 3) uint8 colours of instance ``k`` here."""
        sel = self.instance == int(k)
        return self.points[sel], self.colors[sel]

    def grasp_target(self, k: int) -> np.ndarray:
        """(P,) bool the grasp target of instance ``k`` over ``points``: its points before the contact
        rule (``geometry``), as at step 0 (``run_labels.StepZeroLabels.target``); the planner must not
        count the target's own lowest millimetres as foreign (docs/benchmark/strict-iou.md, session 8)."""
        self.check_present(k)
        return self.geometry == int(k)

    def grasp_request(self, k: int, views=(), voxel_size: float = 0.005):
        """The ``GraspRequest`` for instance ``k``: the whole scene cloud as it is now, the target its
        points before the contact rule (``grasp_target``). At step > 0 pass no ``views``: the
        initial depth views no longer show the scene (cloud-only check)."""
        from clutt3r_core.grasping import GraspRequest

        return GraspRequest(points=self.points, normals=self.normals, target=self.grasp_target(k),
                            instance=int(k), views=tuple(views), voxel_size=float(voxel_size))


def build_scene_after(inp: ChainInputs) -> SceneAfter:
    """The scene after ``inp.history``'s updates (module docstring): removed instances' points
    left out (kept in ``run_*`` as ``gone``), displaced ones moved by their composed motions
    (``compose_motions``; normals turned with them), the added instances' points with PCA normals
    oriented towards ``inp.eyes`` of the update that added them, moved like the instance since."""
    hist = inp.history
    step = len(hist)
    removed = {k: (h.step, h.frame) for h in hist for k in h.removed}
    added_at = {k: (h.step, h.frame) for h in hist for k in h.added}
    n_ids = max(int(inp.num_ids), 1 + max(added_at, default=-1))
    M = compose_motions([zip(h.displaced, h.T_world) for h in hist], n_ids)[step]
    inst0, geo = inp.instance, inp.geometry
    same = geo is inst0  # ChainInputs without geometry: one labelling
    # the points an update moved and dropped with an instance are those the state holds for it:
    # its labels before the contact rule (``geometry.geometry_labels``), its lowest millimetres included
    gone = np.isin(geo, list(removed)) & (geo >= 0)
    pts, nrm = inp.points.astype(np.float64), inp.normals.astype(np.float64)
    moved_ids = np.flatnonzero(np.any(M[:inp.num_ids] != np.eye(4), axis=(1, 2)))
    for k in moved_ids:
        sel = geo == k
        pts[sel] = pts[sel] @ M[k, :3, :3].T + M[k, :3, 3]
        nrm[sel] = nrm[sel] @ M[k, :3, :3].T
    if not same:
        # a point the shown labels give an instance that its geometry does not (none from the contact
        # fill since session 10: its points are the geometry's) stayed in place when that instance
        # moved or left: it is no part of it there
        left = np.isin(inst0, np.concatenate([moved_ids, list(removed)]).astype(np.int64)) & (inst0 != geo) & ~gone
        if left.any():
            inst0 = np.where(left, -1, inst0)
    added = {k: v for k, v in added_at.items() if k not in removed}
    P, C, N, I = [], [], [], []
    for k in sorted(added):
        sel = inp.added_instance == k
        p = inp.added_points[sel].astype(np.float64)  # already moved by the later updates
        # orient as seen from the camera that added it, moved like the object since
        eye = inp.eyes.get(added[k][1])
        T = M[k]
        if eye is not None:
            eye = T[:3, :3] @ eye + T[:3, 3]
        P.append(p)
        C.append(inp.added_colors[sel])
        N.append(oriented_normals(p, eye))
        I.append(np.full(len(p), k, np.int32))
    cat = lambda xs, shape, dt: np.concatenate(xs) if xs else np.zeros(shape, dt)  # noqa: E731
    present = np.setdiff1d(np.union1d(inp.ids, list(added)), list(removed)).astype(np.int32)
    moved = sorted({k for h in hist for k in h.displaced} & set(present.tolist()))
    return SceneAfter(step, inp.n_updates, hist[-1].frame if hist else None, pts, inp.colors, nrm,
                      inst0, gone, cat(P, (0, 3), np.float32), cat(C, (0, 3), np.uint8),
                      cat(N, (0, 3), np.float32), cat(I, 0, np.int32), present, removed, added, tuple(moved), M,
                      inp.run, inp.stale, inp.run_share, None if same else geo, inp.source, inp.corrected_away)


def chain_inputs(run_dir: str | Path, step: int | None = None, seg=None,
                 eyes: Mapping[int, np.ndarray] | None = None) -> ChainInputs:
    """``ChainInputs`` of run ``run_dir`` after its first ``step`` updates (None: all of them),
    read from the run folder and its saved chain.

    Args:
        seg: the run's ``Segmentation`` when already loaded (else ``runs.load_run``).
        eyes: {frame: camera centre (3,) world metres} of the post views (``ChainInputs.eyes``).
    """
    from clutt3r_core.update.state import load_state, state_dirs

    run_dir = Path(run_dir)
    if seg is None:
        from clutt3r_core.runs import load_run

        seg = load_run(run_dir)
    dirs = state_dirs(run_dir)
    step = resolve_step(run_dir, step)
    base = dict(points=seg.points, colors=seg.colors, normals=seg.normals, n_updates=len(dirs),
                eyes=eyes or {}, run=run_dir)
    pre = run_geometry(seg)  # ~30 ms CPU at 120k points (sample_seq4)
    if step == 0:
        return ChainInputs(instance=seg.instance, ids=np.arange(seg.num_instances), num_ids=seg.num_instances,
                           geometry=pre, **base)
    st = load_state(dirs[step - 1])
    hist = st.history[:step]
    if len(hist) != step:
        raise SceneFileError(dirs[step - 1] / "state.json", f"history has {len(hist)} updates, expected {step}")
    from clutt3r_core.update.run_labels import LOG_NAME, run_labels, run_share, stale_note

    stale, share, away = None, None, {}
    inst0, n_run, ids0 = seg.instance, seg.num_instances, np.arange(seg.num_instances)
    corrected = st.labels is not None and st.labels.entries > 0  # as the state's step 0 was built
    if corrected:
        lab = run_labels(run_dir, seg, entries=st.labels.entries)  # the labelling the chain was computed from
        if lab.source.labels_sha256 != st.labels.labels_sha256:
            raise SceneFileError(run_dir / LOG_NAME,
                                 f"replaying its first {st.labels.entries} entries does not give the labels "
                                 f"{dirs[0].name} was computed from (the log was rewritten?)")
        share = run_share(lab.instance, seg, lab.num_ids)
        inst0, n_run, ids0, away = lab.instance, lab.num_ids, lab.ids, lab.gone
    if (run_dir / LOG_NAME).is_file():  # always there for a corrected chain (run_labels above needs it)
        stale = stale_note(run_dir, seg)
    # the state holds the added instances still present, moved by the later updates
    added_ids = [k for h in hist for k in h.added]
    sel = np.isin(st.instance, added_ids)
    geo = held_geometry(geometry_labels(seg, inst0, pre, corrected), seg, [k for h in hist for k in h.removed],
                        state_rows(st.instance, added_ids))
    return ChainInputs(instance=inst0, ids=ids0, num_ids=n_run, history=hist, added_points=st.points[sel],
                       added_colors=st.colors[sel], added_instance=st.instance[sel], stale=stale, run_share=share,
                       geometry=geo, source=st.labels, corrected_away=away, **base)


def scene_after(run_dir: str | Path, step: int | None = None, seg=None,
                eyes: Mapping[int, np.ndarray] | None = None) -> SceneAfter:
    """The scene of run ``run_dir`` after its first ``step`` updates (None: all of them):
    ``build_scene_after(chain_inputs(...))``.

    Args:
        seg: the run's ``Segmentation`` when already loaded (else ``runs.load_run``).
        eyes: {frame: camera centre (3,) world metres} of the post views, to orient the added
            instances' normals (``oriented_normals``); missing frames fall back to +z.
    """
    return build_scene_after(chain_inputs(run_dir, step, seg, eyes))
