"""The trace of a segmentation run: every intermediate, for the viewer, rerun and tests.

Serialised compactly as ``trace.npz`` (arrays) + ``trace.json`` (steps, timings,
config); ``load_trace`` reads back an equal object. The config is the run's typed
``SegmentConfig`` and is read back equal or not at all (``config.config_from_json``).
"""

from __future__ import annotations

import json
import time
import zipfile
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from clutt3r_core.config import SegmentConfig, config_from_json, config_to_json
from clutt3r_core.errors import SceneError, SceneFileError
from clutt3r_core.io.images import atomic_write_bytes, atomic_write_npz
from clutt3r_core.segmentation.grouping import (
    BlockedPairs,
    GroupingResult,
    MergeStep,
    NodeTable,
    ResidualNotes,
    StageStop,
    Substitution,
)
from clutt3r_core.segmentation.trees import InstanceTree
from clutt3r_core.segmentation.vote import VoteResult
from clutt3r_core.surface import SurfaceChoice

__all__ = ["StageTiming", "StageClock", "Trace", "save_trace", "load_trace", "TRACE_VERSION"]

TRACE_VERSION = 1


@dataclass(frozen=True)
class StageTiming:
    stage: str
    seconds: float


class StageClock:
    """Collects StageTiming items: ``with clock("name"): ...`` (the pipeline and the baselines)."""

    def __init__(self) -> None:
        self.items: list[StageTiming] = []

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.items.append(StageTiming(stage, time.perf_counter() - t0))


@dataclass(frozen=True, eq=False)
class Trace:
    """Everything the pipeline computed on the way to the instances.

    Attributes:
        frames: (V,) int32 frames of the initial views, in order.
        trees: per-view containment forests (Sec. III-B.1).
        nodes: all tree nodes in canonical order; leaves are the grouping's start.
        embeddings: (U, D) float32 unit embeddings of every node; ``embedder`` names the backend.
        occupancy: (U, K) float32 o_i(k) of every node over super-voxels (eq. 2).
        s_spatial, s_semantic: (U, U) float32 leaf-graph edge weights, NaN = no edge.
        grouping: merges in order, substitutions, final groups (Algorithm 1, Sec. III-B.3).
        vote: per-super-voxel votes and the instances (Sec. III-B.4).
        timings: seconds per stage.
        embedder: name of the embedding backend used for S_semantic.
        config: the run's ``SegmentConfig`` (saved as JSON, read back equal).
        surface: what the fusion measured and did with the raw points (``surface.SurfaceChoice``:
            the views' depth disagreement, surface estimate or not, the noise that limited its
            moves); None with ``pointcloud.surface = "voxel-mean"`` and in older traces.
    """

    frames: np.ndarray
    trees: tuple[InstanceTree, ...]
    nodes: NodeTable
    embeddings: np.ndarray
    occupancy: np.ndarray
    s_spatial: np.ndarray
    s_semantic: np.ndarray
    grouping: GroupingResult
    vote: VoteResult
    timings: tuple[StageTiming, ...]
    embedder: str
    config: SegmentConfig
    surface: SurfaceChoice | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.config, SegmentConfig):
            raise SceneError(f"Trace.config must be a SegmentConfig, got {type(self.config).__name__}")

    def timing(self, stage: str) -> float:
        return sum(t.seconds for t in self.timings if t.stage == stage)

    def node_instance(self, follow_substitutions: bool = False) -> np.ndarray:
        """(U,) int32 instance of every node through its final group, -1 = none.

        A node is in instance k when it is a member of group ``vote.instance_group[k]``.
        With ``follow_substitutions`` a residual leaf that a substitution replaced by its
        parent (Sec. III-B.3; it is then in no group) gets the parent's instance, as in
        ``instance_tree.json``'s ``leaf2inst``.
        """
        out = np.full(len(self.nodes), -1, np.int32)
        for k, gi in enumerate(self.vote.instance_group):
            out[list(self.grouping.groups[int(gi)])] = k
        if follow_substitutions:
            for s in self.grouping.substitutions:
                out[list(s.replaced)] = out[s.parent]
        return out

    def groups_at(self, n_events: int) -> list[tuple[int, ...]]:
        """The groups after the first ``n_events`` events (merges and substitutions, in order).

        ``groups_at(0)`` is every non-background leaf alone; ``groups_at(len(events))``
        equals ``grouping.groups``.
        """
        nodes = self.nodes
        groups = {(int(i),) for i in np.flatnonzero(nodes.is_leaf & ~nodes.background)}
        for kind, idx in self.grouping.events[:n_events]:
            if kind == "merge":
                m = self.grouping.merges[idx]
                groups.discard(m.a)
                groups.discard(m.b)
                groups.add(tuple(sorted(m.a + m.b)))
            else:
                s = self.grouping.substitutions[idx]
                for r in s.replaced:
                    groups.discard((r,))
                groups.add((s.parent,))
        return sorted(groups, key=lambda g: g[0])


def _tree_to_json(t: InstanceTree) -> dict:
    return {
        "frame": t.frame,
        "mask_ids": t.mask_ids.tolist(),
        "parent": t.parent.tolist(),
        "areas": t.areas.tolist(),
        "dropped_ids": t.dropped_ids.tolist(),
    }


def _tree_from_json(d: dict) -> InstanceTree:
    return InstanceTree(
        frame=int(d["frame"]),
        mask_ids=np.asarray(d["mask_ids"], np.int32),
        parent=np.asarray(d["parent"], np.int32),
        areas=np.asarray(d["areas"], np.int64),
        dropped_ids=np.asarray(d["dropped_ids"], np.int32),
    )


def _nan_as_null(record) -> dict:
    """A dataclass record's fields with NaN as None: strict JSON (``_null_as_nan`` reads it back)."""
    return {k: (None if isinstance(x, float) and x != x else x) for k, x in asdict(record).items()}


def _null_as_nan(fields: dict) -> dict:
    """The fields ``_nan_as_null`` wrote, None back to NaN."""
    return {k: (float("nan") if x is None else x) for k, x in fields.items()}


def save_trace(trace: Trace, folder: str | Path) -> Path:
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n, v = trace.nodes, trace.vote
    occ = trace.occupancy
    rows, cols = np.nonzero(occ)
    arrays = {
        "frames": trace.frames,
        "node_frame": n.frame, "node_view": n.view, "node_mask_id": n.mask_id, "node_parent": n.parent,
        "node_is_leaf": n.is_leaf, "node_background": n.background,
        # float32, as used for S_semantic (issue 13: float16 moved cosines by up to 6e-4 on a hard
        # generated scene, so a pair at tau_sem recomputed from the trace could disagree with the run)
        "embeddings": trace.embeddings.astype(np.float32),
        "occ_shape": np.asarray(occ.shape, np.int64),
        "occ_rows": rows.astype(np.int32), "occ_cols": cols.astype(np.int32),
        "occ_vals": occ[rows, cols].astype(np.float32),
        "s_spatial": trace.s_spatial.astype(np.float32), "s_semantic": trace.s_semantic.astype(np.float32),
        "sv_label": v.sv_label, "sv_group": v.sv_group, "sv_vote": v.sv_vote,
        "sv_runner_up": v.sv_runner_up, "sv_coverage": v.sv_coverage,
        "instance_group": v.instance_group, "scores": v.scores,
    }
    # explanations of decisions not taken (absent in older traces; load_trace leaves them None)
    if v.sv_reason is not None:
        arrays.update(sv_top_group=v.sv_top_group, sv_top_vote=v.sv_top_vote.astype(np.float32),
                      sv_reason=v.sv_reason, group_points=v.group_points)
    if v.span_cleared is not None:  # ours (session 9): occupancies the vote ignored (segmentation.span)
        arrays.update(span_cleared=np.asarray(v.span_cleared, np.int32).reshape(-1, 2))
    g = trace.grouping
    if g.blocked is not None:
        arrays.update({f"blocked_{f}": getattr(g.blocked, f) for f in ("stop", "a", "b", "rule", "score")})
    if g.residuals is not None:
        arrays.update({f"residual_{f}": getattr(g.residuals, f) for f in ("node", "round", "reason", "other")})
    atomic_write_npz(folder / "trace.npz", **arrays)
    meta = {
        "version": TRACE_VERSION,
        "embedder": trace.embedder,
        "trees": [_tree_to_json(t) for t in trace.trees],
        "groups": [list(x) for x in g.groups],
        "merges": [asdict(m) for m in g.merges],
        "substitutions": [asdict(s) for s in g.substitutions],
        "events": [list(e) for e in g.events],
        "timings": [asdict(t) for t in trace.timings],
        "config": config_to_json(trace.config),
    }
    if trace.surface is not None:  # NaN: not measured
        meta["surface"] = _nan_as_null(trace.surface)
    if g.stops is not None:  # NaN: no pair left
        meta["stops"] = [_nan_as_null(st) for st in g.stops]
    atomic_write_bytes(folder / "trace.json", json.dumps(meta, indent=1).encode())
    return folder


def load_trace(folder: str | Path) -> Trace:
    """Read a trace written by ``save_trace``; ``SceneFileError`` naming the file and the problem
    (for the config: the field) when it cannot be read back exactly."""
    folder = Path(folder)
    jpath, npath = folder / "trace.json", folder / "trace.npz"
    for p in (jpath, npath):
        if not p.is_file():
            raise SceneFileError(p, "missing: not a saved trace")
    try:
        meta = json.loads(jpath.read_text())
    except json.JSONDecodeError as e:
        raise SceneFileError(jpath, f"not valid JSON ({e.msg})") from None
    if meta.get("version") != TRACE_VERSION:
        raise SceneFileError(jpath, f"trace version {meta.get('version')} is not {TRACE_VERSION}")
    if "config" not in meta:
        raise SceneFileError(jpath, "config: missing (the run's settings are unknown)")
    config = config_from_json(meta["config"], jpath)
    try:
        z = dict(np.load(npath))
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, zlib.error, NotImplementedError, RuntimeError) as e:
        # a truncated / corrupt npz (zipfile: unknown version or method, member flagged encrypted)
        raise SceneFileError(npath, f"unreadable: {e}") from None
    occ = np.zeros(tuple(z["occ_shape"]), np.float32)
    occ[z["occ_rows"], z["occ_cols"]] = z["occ_vals"]
    nodes = NodeTable(
        frame=z["node_frame"], view=z["node_view"], mask_id=z["node_mask_id"], parent=z["node_parent"],
        is_leaf=z["node_is_leaf"], background=z["node_background"],
    )
    tup = lambda xs: tuple(int(x) for x in xs)  # noqa: E731
    grouping = GroupingResult(
        groups=tuple(tup(x) for x in meta["groups"]),
        merges=tuple(MergeStep(**{**m, "a": tup(m["a"]), "b": tup(m["b"])}) for m in meta["merges"]),
        substitutions=tuple(Substitution(**{**s, "replaced": tup(s["replaced"])}) for s in meta["substitutions"]),
        events=tuple((str(k), int(i)) for k, i in meta["events"]),
        stops=tuple(StageStop(**_null_as_nan(st)) for st in meta["stops"]) if "stops" in meta else None,
        blocked=BlockedPairs(*(z[f"blocked_{f}"] for f in ("stop", "a", "b", "rule", "score")))
        if "blocked_stop" in z else None,
        residuals=ResidualNotes(*(z[f"residual_{f}"] for f in ("node", "round", "reason", "other")))
        if "residual_node" in z else None,
    )
    vote = VoteResult(
        sv_label=z["sv_label"], sv_group=z["sv_group"], sv_vote=z["sv_vote"], sv_runner_up=z["sv_runner_up"],
        sv_coverage=z["sv_coverage"], instance_group=z["instance_group"], scores=z["scores"],
        sv_top_group=z.get("sv_top_group"),
        sv_top_vote=z["sv_top_vote"].astype(np.float32) if "sv_top_vote" in z else None,
        sv_reason=z.get("sv_reason"), group_points=z.get("group_points"),
        span_cleared=z["span_cleared"].reshape(-1, 2) if "span_cleared" in z else None,
    )
    return Trace(
        frames=z["frames"],
        trees=tuple(_tree_from_json(t) for t in meta["trees"]),
        nodes=nodes,
        embeddings=z["embeddings"].astype(np.float32),
        occupancy=occ,
        s_spatial=z["s_spatial"],
        s_semantic=z["s_semantic"],
        grouping=grouping,
        vote=vote,
        timings=tuple(StageTiming(**t) for t in meta["timings"]),
        embedder=meta["embedder"],
        config=config,
        surface=SurfaceChoice(**_null_as_nan(meta["surface"])) if "surface" in meta else None,
    )
