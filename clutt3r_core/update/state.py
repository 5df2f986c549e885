"""The scene state that updates act on, saved as a chain of states beside the run.

A state is the run's labelled cloud after zero or more updates: displaced instances'
points moved, removed instances' points dropped, every other point unchanged; instance
ids stay the run's ids for ever (a removed id is never reused). Each instance keeps the
embedding it had in the run (the mean of its masks' embeddings over the initial views,
Sec. III-C.1 "stored instance embeddings"), so later updates match against the same
multi-view evidence.

On disk (``save_state``), one folder per update, by default under the run::

    RUN/updates/01_frame_000008/
        state.npz        points (N,3) f32, colors (N,3) u8, instance (N,) i32,
                         instance_ids (K,) i32, embeddings (K,D) f32
        state.json       {"schema_version", "step", "frame", "embedder", "voxel_size",
                          "run", "parent", "history": [...]}
        update.json      the update that produced it (issue 10 schema)
        pose.npz         every pose iteration of every displaced instance (replay)

``latest_state(run)`` returns the last state of the chain (the run itself at step 0), so
``clutt3r update RUN --frame 8`` then ``--frame 9`` chains.

Corrections (session 7, ``run_labels``): ``state_from_run`` starts from the run's labelling
after its correction log (the Edit tab's merges, splits, deletes), so the ids are the corrected
ids; ``state.json`` "labels" records which log state it was (``LabelSource``), and update.json
a "corrections" object when the log had entries.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import atomic_write_bytes, atomic_write_npz
from clutt3r_core.update.geometry import corrected_geometry_labels, fused_count, run_geometry
from clutt3r_core.update.run_labels import LabelSource, RunLabels, run_share
from clutt3r_core.update.types import LOSS_NAMES, PoseTrace, UpdateResult

__all__ = [
    "HistoryEntry",
    "SceneState",
    "state_from_run",
    "state_from_segmentation",
    "apply_update",
    "moved_points",
    "save_state",
    "load_state",
    "latest_state",
    "state_dirs",
    "STATE_VERSION",
]

STATE_VERSION = 1


def _ro(a: np.ndarray) -> np.ndarray:
    a = np.ascontiguousarray(a)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class HistoryEntry:
    """One past update of a state's chain.

    Attributes:
        step: 1 for the first update of the run, 2 for the next, ...
        frame: the post-interaction frame it processed.
        removed: ids reported removed (dropped from the state).
        displaced: ids moved.
        T_world: (len(displaced), 4, 4) their motions.
        occluded: ids that were not visible (kept unchanged).
        added: ids of the instances the update added (status "new", ``newobj.py``).
    """

    step: int
    frame: int
    removed: tuple[int, ...]
    displaced: tuple[int, ...]
    T_world: np.ndarray
    occluded: tuple[int, ...] = ()
    added: tuple[int, ...] = ()

    @staticmethod
    def of_result(result: UpdateResult, step: int) -> "HistoryEntry":
        """The record of update ``result`` applied as update ``step`` of a chain (``apply_update``;
        the viewer's loaded chain, ``clutt3r_viewer.scene_step``)."""
        displaced = [r for r in result.instances if r.status == "displaced"]
        return HistoryEntry(
            step=int(step), frame=result.frame, removed=tuple(int(x) for x in result.by_status("removed")),
            displaced=tuple(r.instance for r in displaced),
            T_world=np.stack([r.T_world for r in displaced]) if displaced else np.zeros((0, 4, 4)),
            occluded=result.by_status("occluded"), added=tuple(sorted(result.by_status("new"))),
        )

    def to_json(self) -> dict:
        return {"step": self.step, "frame": self.frame, "removed": list(self.removed),
                "displaced": list(self.displaced), "T_world": np.round(self.T_world, 8).tolist(),
                "occluded": list(self.occluded), "added": list(self.added)}

    @staticmethod
    def from_json(d: dict) -> "HistoryEntry":
        return HistoryEntry(int(d["step"]), int(d["frame"]), tuple(int(x) for x in d["removed"]),
                            tuple(int(x) for x in d["displaced"]),
                            np.asarray(d["T_world"], np.float64).reshape(-1, 4, 4),
                            tuple(int(x) for x in d.get("occluded", [])), tuple(int(x) for x in d.get("added", [])))


@dataclass(frozen=True, eq=False)
class SceneState:
    """The labelled scene before an update.

    Attributes:
        points: (N, 3) float32 world metres.
        colors: (N, 3) uint8.
        instance: (N,) int32 the run's instance id of each point, -1 = none.
        instance_ids: (K,) int32 ids present, ascending.
        embeddings: (K, D) float32 unit stored instance embeddings (rows follow instance_ids).
        embedder: name of the mask embedder that made them (new masks use the same).
        voxel_size: point spacing in metres (the run's voxel size).
        step: 0 for the run itself, n after n updates.
        history: the updates that led here, in order.
        run: the run folder the chain started from (None for an in-memory state).
        labels: the labelling step 0 was built from (corrections, ``run_labels``); None = the
            segmentation as given (in-memory states, chains written before session 7).
    """

    points: np.ndarray
    colors: np.ndarray
    instance: np.ndarray
    instance_ids: np.ndarray
    embeddings: np.ndarray
    embedder: str
    voxel_size: float = 0.005
    step: int = 0
    history: tuple[HistoryEntry, ...] = ()
    run: Path | None = None
    labels: LabelSource | None = None

    def __post_init__(self) -> None:
        p = np.asarray(self.points, np.float32)
        n = len(p)
        if p.shape != (n, 3):
            raise SceneError(f"SceneState.points must be (N, 3), got {p.shape}")
        c = np.asarray(self.colors, np.uint8)
        inst = np.asarray(self.instance, np.int32)
        if c.shape != (n, 3) or inst.shape != (n,):
            raise SceneError("SceneState: points (N,3), colors (N,3) and instance (N,) must agree")
        ids = np.asarray(self.instance_ids, np.int32)
        emb = np.asarray(self.embeddings, np.float32)
        if emb.ndim != 2 or emb.shape[0] != len(ids):
            raise SceneError(f"SceneState: embeddings must be (K={len(ids)}, D), got {emb.shape}")
        if np.any(np.diff(ids) <= 0):
            raise SceneError("SceneState.instance_ids must be strictly ascending")
        extra = set(np.unique(inst[inst >= 0]).tolist()) - set(ids.tolist())
        if extra:
            raise SceneError(f"SceneState: points carry instance ids {sorted(extra)} that are not present")
        for name, a in (("points", p), ("colors", c), ("instance", inst), ("instance_ids", ids), ("embeddings", emb)):
            object.__setattr__(self, name, _ro(a))
        object.__setattr__(self, "history", tuple(self.history))

    def points_of(self, k: int) -> np.ndarray:
        return self.points[self.instance == k]

    def embedding_of(self, k: int) -> np.ndarray:
        return self.embeddings[int(np.searchsorted(self.instance_ids, k))]


def state_from_segmentation(seg, voxel_size: float = 0.005, run: Path | None = None,
                            instance_embeddings: np.ndarray | None = None,
                            labels: RunLabels | None = None) -> SceneState:
    """Step 0 of a run: its cloud, with instance embeddings = normalised mean of the
    instance's masks' embeddings (``seg.trace.embeddings``), or ``instance_embeddings``
    (K, D) when given (e.g. multi-view instance embeddings of a language backend).

    ``labels``: a corrected labelling of the run (``run_labels``); the state then carries its
    ids and each corrected instance's embedding is the point-weighted mean of the (unit) embeddings
    of the run instances its points came from (a merge averages its parts, a split-off part
    inherits its source's; one made only of background points gets a zero embedding, which
    matches no mask semantically)."""
    k = seg.num_instances
    if instance_embeddings is not None:
        emb = np.asarray(instance_embeddings, np.float32)
        if emb.shape[0] != k:
            raise SceneError(f"instance_embeddings has {emb.shape[0]} rows for {k} instances")
    else:
        e = seg.trace.embeddings
        emb = np.zeros((k, e.shape[1]), np.float32)
        for i in range(k):
            nodes = list(seg.instance_nodes(i))
            if nodes:  # an unvoted-fallback instance has no masks: a zero embedding (matches none)
                emb[i] = e[nodes].mean(axis=0)
    norm = np.linalg.norm(emb, axis=1, keepdims=True)
    emb = np.divide(emb, norm, out=np.zeros_like(emb), where=norm > 0)
    # The fusion's rim voxels (the run's last ``trace.surface.rim`` points, ``clutt3r_core.rim``)
    # stay out of the update's geometry: each is one unverified raw point, labelled after the vote
    # by its neighbours, and on real depth many lie just beside their object (depth-edge points).
    # Measured on sample_seq1 frame 8: with them every fitted instance's IoU after the update was
    # 0.02-0.05 lower and the moved clamp was reported static; without them the update is the
    # one of the cloud without rim voxels (identical results). The viewer still moves them with
    # their instance (it reads the run's points).
    n = fused_count(seg)
    if labels is None:
        return SceneState(points=seg.points[:n], colors=seg.colors[:n], instance=_geometry_labels(seg, n),
                          instance_ids=np.arange(k, dtype=np.int32), embeddings=emb,
                          embedder=seg.trace.embedder, voxel_size=voxel_size, run=run)
    if len(labels.instance) != len(seg.points):
        raise SceneError(f"corrected labels have {len(labels.instance)} points, the run {len(seg.points)}")
    # the trimmed points (contact, weak echoes) mapped through the corrections (``corrected_geometry_labels``; the
    # grasp target at step 0 reads the same mapping, ``run_labels.StepZeroLabels.geometry``)
    inst = corrected_geometry_labels(seg, labels.instance, n)
    ids = np.unique(inst[inst >= 0]).astype(np.int32)  # rim-only instances have no point here
    cemb = (run_share(labels.instance, seg, labels.num_ids)[ids] @ emb).astype(np.float32)
    norm = np.linalg.norm(cemb, axis=1, keepdims=True)
    cemb = np.divide(cemb, norm, out=np.zeros_like(cemb), where=norm > 0)
    return SceneState(points=seg.points[:n], colors=seg.colors[:n], instance=inst, instance_ids=ids,
                      embeddings=cemb, embedder=seg.trace.embedder, voxel_size=voxel_size, run=run,
                      labels=labels.source)


def _geometry_labels(seg, n: int) -> np.ndarray:
    """(n,) the labels of the run's first n points that the update's geometry reads: the objects'
    geometry (``geometry.run_geometry``: the run's own labels, or where the run trimmed them after the
    vote, the labels before the weak-echo and contact rules, with the contact fill's points).
    Measured on sample_seq1 frame 8: with the contact's labels the moved clamp was reported static
    (its lowest millimetres unlabelled), as with the rim voxels above (docs/benchmark/strict-iou.md,
    session 8)."""
    return run_geometry(seg)[:n]


def state_from_run(run_dir: str | Path) -> SceneState:
    """Step 0 of a saved run folder: its labelling after the corrections in effect in its log
    (``run_labels``; the run as segmented when it has none). ``state.labels`` records which."""
    from clutt3r_core.runs import load_run, run_voxel_size
    from clutt3r_core.update.run_labels import run_labels

    run_dir = Path(run_dir)
    seg = load_run(run_dir)
    voxel = run_voxel_size(seg)
    labels = run_labels(run_dir, seg)
    if labels.source.entries == 0:  # no log: exactly the state it always was, recorded as such
        return replace(state_from_segmentation(seg, voxel_size=voxel, run=run_dir), labels=labels.source)
    return state_from_segmentation(seg, voxel_size=voxel, run=run_dir, labels=labels)


def moved_points(state: SceneState, motions: dict[int, np.ndarray]) -> np.ndarray:
    """(N, 3) float64 stored points, those of each instance ``k`` in ``motions`` moved by
    ``motions[k]`` ((4, 4) world motion), the others as stored."""
    pts = state.points.astype(np.float64)  # a copy
    for k, T in motions.items():
        sel = state.instance == k
        pts[sel] = pts[sel] @ T[:3, :3].T + T[:3, 3]
    return pts


def apply_update(state: SceneState, result: UpdateResult) -> SceneState:
    """The next state: displaced instances' points moved by their T_world, removed dropped,
    static and occluded unchanged, added instances (``result.added``, status "new") appended
    with their points, colours and embedding; the update appended to the history."""
    pts = moved_points(state, {r.instance: r.T_world for r in result.instances if r.status == "displaced"})
    removed = np.array(result.by_status("removed"), np.int32)
    keep = ~np.isin(state.instance, removed)
    keep_ids = ~np.isin(state.instance_ids, removed)
    added = sorted(result.added, key=lambda a: a.instance)
    if {a.instance for a in added} != set(result.by_status("new")):
        raise SceneError(f"frame {result.frame}: the 'new' instances {sorted(result.by_status('new'))} must come "
                         f"with their points (UpdateResult.added: {[a.instance for a in added]})")
    if added and added[0].instance <= int(state.instance_ids.max(initial=-1)):
        raise SceneError(f"frame {result.frame}: added instance id {added[0].instance} is not above the state's ids")
    entry = HistoryEntry.of_result(result, state.step + 1)
    D = state.embeddings.shape[1]
    emb_new = np.zeros((len(added), D), np.float32)
    for j, a in enumerate(added):
        if a.embedding is not None and a.embedding.shape == (D,):
            emb_new[j] = a.embedding
    return SceneState(
        points=np.concatenate([pts[keep].astype(np.float32)] + [a.points for a in added]),
        colors=np.concatenate([state.colors[keep]] + [a.colors for a in added]),
        instance=np.concatenate([state.instance[keep]] + [np.full(len(a.points), a.instance, np.int32) for a in added]),
        instance_ids=np.concatenate([state.instance_ids[keep_ids], np.array([a.instance for a in added], np.int32)]),
        embeddings=np.concatenate([state.embeddings[keep_ids], emb_new]),
        embedder=state.embedder, voxel_size=state.voxel_size, step=state.step + 1,
        history=state.history + (entry,), run=state.run, labels=state.labels,
    )


def state_dirs(run_dir: str | Path) -> list[Path]:
    """The saved states of a run's chain (``RUN/updates/*/state.json``), by step."""
    root = Path(run_dir) / "updates"
    if not root.is_dir():
        return []
    out = []
    for d in root.iterdir():
        if (d / "state.json").is_file():
            try:
                step = int(json.loads((d / "state.json").read_text())["step"])
            except (ValueError, KeyError, json.JSONDecodeError):
                raise SceneFileError(d / "state.json", "not a valid update state (no integer 'step')") from None
            out.append((step, d))
    return [d for _, d in sorted(out)]


def save_state(state: SceneState, folder: str | Path, result: UpdateResult | None = None,
               parent: Path | None = None) -> Path:
    """Write a state folder (module docstring); every file atomically."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_npz(
        folder / "state.npz", points=state.points, colors=state.colors, instance=state.instance,
        instance_ids=state.instance_ids, embeddings=state.embeddings)
    meta = {
        "schema_version": STATE_VERSION, "step": state.step,
        "frame": state.history[-1].frame if state.history else None,
        "embedder": state.embedder, "voxel_size": state.voxel_size,
        "run": None if state.run is None else str(Path(state.run).resolve()),
        "parent": None if parent is None else str(Path(parent).resolve()),
        "history": [h.to_json() for h in state.history],
        "labels": None if state.labels is None else state.labels.to_json(),
    }
    atomic_write_bytes(folder / "state.json", json.dumps(meta, indent=1).encode())
    if result is not None:
        # the embedder that associated (issue 10 schema + this field): S_semantic depends on it
        doc = {**result.to_json(), "embedder": state.embedder}
        if state.labels is not None and state.labels.entries > 0:
            # its ids are the corrected ones (docs/update.md, session 7); absent = the run as segmented
            doc["corrections"] = state.labels.to_json()
        atomic_write_bytes(folder / "update.json", json.dumps(doc, indent=1).encode())
        arrays = {}
        for r in result.instances:
            if r.pose is not None:
                t = r.pose.trace
                arrays[f"i{r.instance}_stage"] = t.stage
                arrays[f"i{r.instance}_T_world"] = t.T_world
                arrays[f"i{r.instance}_losses"] = t.losses
                arrays[f"i{r.instance}_iou"] = t.iou
        arrays["loss_names"] = np.array(LOSS_NAMES)
        atomic_write_npz(folder / "pose.npz", **arrays)
    return folder


def load_pose_traces(folder: str | Path) -> dict[int, PoseTrace]:
    """The pose iterations saved with an update: instance id -> PoseTrace."""
    path = Path(folder) / "pose.npz"
    if not path.is_file():
        return {}
    z = dict(np.load(path))
    out = {}
    for key in z:
        if key.endswith("_stage"):
            k = key[1:-len("_stage")]
            out[int(k)] = PoseTrace(z[f"i{k}_stage"], z[f"i{k}_T_world"], z[f"i{k}_losses"], z[f"i{k}_iou"])
    return out


def load_state(folder: str | Path) -> SceneState:
    """A saved state folder, or a run folder (its step 0)."""
    folder = Path(folder)
    jpath = folder / "state.json"
    if not jpath.is_file():
        from clutt3r_core.runs import is_run_folder

        if is_run_folder(folder):
            return state_from_run(folder)
        raise SceneFileError(folder, "neither a run folder nor an update state (no state.json)")
    try:
        meta = json.loads(jpath.read_text())
        z = dict(np.load(folder / "state.npz"))
    except (OSError, ValueError) as e:
        raise SceneFileError(folder, f"unreadable update state: {e}") from None
    if meta.get("schema_version") != STATE_VERSION:
        raise SceneFileError(jpath, f"state schema_version {meta.get('schema_version')} is not {STATE_VERSION}")
    return SceneState(
        points=z["points"], colors=z["colors"], instance=z["instance"], instance_ids=z["instance_ids"],
        embeddings=z["embeddings"], embedder=meta["embedder"], voxel_size=float(meta["voxel_size"]),
        step=int(meta["step"]), history=tuple(HistoryEntry.from_json(h) for h in meta["history"]),
        run=None if meta.get("run") is None else Path(meta["run"]),
        labels=LabelSource.from_json(meta["labels"]) if meta.get("labels") else None,
    )


def latest_state(run_dir: str | Path) -> tuple[SceneState, Path]:
    """The last state of a run's chain and its folder (the run folder itself at step 0)."""
    dirs = state_dirs(run_dir)
    if dirs:
        return load_state(dirs[-1]), dirs[-1]
    return state_from_run(run_dir), Path(run_dir)
