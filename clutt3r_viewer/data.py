"""What the viewer shows, derived once from a run (and its scene, when known).

Pure functions over the core's public types (``Segmentation``, ``Trace``, ``Scene``);
nothing here imports viser, so every derivation is testable without a browser.
Conventions: docs/conventions.md (metres, world z up, node ids index ``trace.nodes``,
-1 = none).
"""

from __future__ import annotations

import colorsys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.pipeline import Segmentation
from clutt3r_core.grasping import GraspSet
from clutt3r_core.scene import Scene, View
from clutt3r_core.update import UpdateFrame
from clutt3r_core.segmentation.span import cleared_occupancy
from clutt3r_core.segmentation.trace import Trace
from clutt3r_core.segmentation.vote import VoteConfig, supervoxel_vote

__all__ = [
    "PALETTE",
    "GREY",
    "label_colors",
    "ramp_colors",
    "lod_indices",
    "GraspSet",
    "UpdateFrame",
    "ViewerData",
    "build_viewer_data",
    "node_label",
    "event_text",
]

GREY = np.array([110, 110, 110], np.uint8)


def _palette(n: int = 64) -> np.ndarray:
    # golden-ratio hue steps: neighbouring ids get clearly different hues
    out = []
    for i in range(n):
        h = (i * 0.618033988749895) % 1.0
        s = 0.65 + 0.3 * ((i // 7) % 2)
        v = 0.95 - 0.2 * ((i // 3) % 2)
        out.append([round(255 * c) for c in colorsys.hsv_to_rgb(h, s, v)])
    return np.asarray(out, np.uint8)


PALETTE = _palette()
"""(64, 3) uint8 distinct colours; id k gets ``PALETTE[k % 64]``."""


def label_colors(labels: np.ndarray, none: np.ndarray = GREY) -> np.ndarray:
    """(N,) int labels (-1 = none) -> (N, 3) uint8 colours."""
    labels = np.asarray(labels)
    out = PALETTE[np.maximum(labels, 0) % len(PALETTE)].copy()
    out[labels < 0] = none
    return out


def ramp_colors(x: np.ndarray, lo: float = 0.0, hi: float = 1.0) -> np.ndarray:
    """(N,) float in [lo, hi] -> (N, 3) uint8 on a blue -> yellow -> red ramp (NaN -> grey)."""
    x = np.asarray(x, np.float64)
    t = np.clip((x - lo) / max(hi - lo, 1e-9), 0.0, 1.0)
    stops = np.array([[40, 70, 200], [60, 190, 220], [250, 220, 60], [230, 50, 40]], np.float64)
    pos = np.nan_to_num(t, nan=0.0) * (len(stops) - 1)
    i = np.minimum(pos.astype(int), len(stops) - 2)
    f = (pos - i)[:, None]
    out = (stops[i] * (1 - f) + stops[i + 1] * f).astype(np.uint8)
    out[~np.isfinite(x)] = GREY
    return out


def lod_indices(n: int, max_points: int, seed: int = 0) -> np.ndarray:
    """Sorted indices of a deterministic uniform subset of ``min(n, max_points)`` of n points.

    ``max_points <= 0`` keeps all. A random subset (not a stride) avoids moire on
    voxel-ordered clouds.
    """
    if max_points <= 0 or n <= max_points:
        return np.arange(n, dtype=np.int64)
    rng = np.random.default_rng(seed)
    return np.sort(rng.choice(n, size=max_points, replace=False)).astype(np.int64)


@dataclass(frozen=True, eq=False)
class ViewerData:
    """A run prepared for display.

    Attributes:
        seg: the segmentation (points in world metres, instances, trace).
        views: initial views in trace order (``trace.frames``), or () when the scene is unknown.
        sv_count: (K,) float64 raw points per super-voxel.
        sv_centroid: (K, 3) float64 count-weighted centroid of every super-voxel, metres.
        node_centroid: (U, 3) float64 3D centroid of every node's mask (occupancy-weighted
            super-voxel centroids), NaN where the mask touches no super-voxel.
        node_group: (U,) int32 final group of each node, -1 = in none.
        node_instance: (U,) int32 instance of each node (via its final group), -1 = none.
        residual: (U,) bool leaves left alone in their final group (Sec. III-B.3).
        substituted: (U,) bool parents substituted for their residual leaves.
        replaced: (U,) bool leaves that a substituted parent replaced.
        edges: (E, 2) int64 node pairs (i < j) of non-background leaves of different views
            with a finite S_spatial or S_semantic (the leaf graph).
        edge_spatial, edge_semantic: (E,) float32 weights of those edges (NaN = none).
        grasps: grasp candidates, or None.
        updates: post-interaction frames to replay, () when there are none.
        scene_root: folder the scene came from, or None.
    """

    seg: Segmentation
    views: tuple[View, ...]
    sv_count: np.ndarray
    sv_centroid: np.ndarray
    node_centroid: np.ndarray
    node_group: np.ndarray
    node_instance: np.ndarray
    residual: np.ndarray
    substituted: np.ndarray
    replaced: np.ndarray
    edges: np.ndarray
    edge_spatial: np.ndarray
    edge_semantic: np.ndarray
    grasps: GraspSet | None = None
    updates: tuple[UpdateFrame, ...] = ()
    scene_root: Path | None = None
    _cache: dict = field(default_factory=dict, repr=False)

    @property
    def trace(self) -> Trace:
        return self.seg.trace

    @property
    def num_events(self) -> int:
        return len(self.trace.grouping.events)

    @property
    def centre(self) -> np.ndarray:
        """(3,) float64 centre of the cloud's bounding box (display offset, metres)."""
        p = self.seg.points
        if len(p) == 0:
            return np.zeros(3)
        return (p.min(axis=0).astype(np.float64) + p.max(axis=0)) / 2

    def view_nodes(self, vi: int) -> np.ndarray:
        """Node indices of view ``vi`` (trace order)."""
        return np.flatnonzero(self.trace.nodes.view == vi)

    def node_mask(self, i: int) -> np.ndarray | None:
        """(H, W) bool mask of node i, or None when the scene's images are unknown."""
        if not self.views:
            return None
        n = self.trace.nodes
        v = self.views[int(n.view[i])]
        if v.masks is None:
            return None
        return v.masks.mask(v.masks.index_of(int(n.mask_id[i])))  # one mask: .masks would build and keep the whole stack

    def node_points(self, i: int) -> np.ndarray:
        """(N,) bool: points of the super-voxels the node's mask covers at least the vote's
        ``min_coverage`` of (o_i(k) >= it, the same guard the Replay highlight uses), so a leaf
        whose mask bleeds a few pixels onto the table does not light up the whole table. Falls
        back to every occupied super-voxel (o_i(k) > 0) when none passes (a sliver of a mask)."""
        occ = self.trace.occupancy[int(i)]
        on = occ >= max(float(self.trace.config.vote.min_coverage), 1e-6)
        if not on.any():
            on = occ > 0
        return on[self.seg.sv_labels]

    def neighbours(self, i: int) -> list[tuple[int, float, float]]:
        """Leaf-graph neighbours of node i as (node, S_spatial, S_semantic), by S_spatial then S_semantic, descending."""
        sel = (self.edges[:, 0] == i) | (self.edges[:, 1] == i)
        other = np.where(self.edges[sel, 0] == i, self.edges[sel, 1], self.edges[sel, 0])
        sp = np.nan_to_num(self.edge_spatial[sel], nan=-1.0)
        se = np.nan_to_num(self.edge_semantic[sel], nan=-1.0)
        order = np.lexsort((-se, -sp))
        return [(int(other[k]), float(self.edge_spatial[sel][k]), float(self.edge_semantic[sel][k])) for k in order]

    # -- grouping replay -------------------------------------------------------------

    def replay_sv_group(self, n_events: int) -> np.ndarray:
        """(K,) int64 super-voxel labels after the first ``n_events`` grouping events.

        Runs the core's super-voxel vote (same config as the run) on ``Trace.groups_at(n)``;
        a super-voxel's label is the **first node** of the group that wins it (-1 = none),
        so a group keeps its colour when another group merges into it.
        """
        n_events = int(np.clip(n_events, 0, self.num_events))
        key = ("replay", n_events)
        if key not in self._cache:
            tr = self.trace
            groups = tuple(tuple(g) for g in tr.groups_at(n_events))
            occ = tr.occupancy
            if n_events == self.num_events and tr.vote.span_cleared is not None:
                # the final groups' vote ignored the spanning masks' occupancies (core segmentation.span)
                occ = cleared_occupancy(occ, tr.vote.span_cleared)
            vote = supervoxel_vote(
                groups, occ, self.sv_count, self.seg.sv_support,
                np.nan_to_num(tr.s_spatial, nan=0.0), len(tr.frames), _vote_config(tr),
            )
            first = np.array([g[0] for g in groups] or [0], np.int64)
            lab = np.full(len(vote.sv_label), -1, np.int64)
            ok = vote.sv_label >= 0
            lab[ok] = first[vote.instance_group[vote.sv_label[ok]]]
            self._cache[key] = (lab, len(groups))
        return self._cache[key][0]

    def replay_num_groups(self, n_events: int) -> int:
        self.replay_sv_group(n_events)
        return self._cache[("replay", int(np.clip(n_events, 0, self.num_events)))][1]

    # -- language --------------------------------------------------------------------

    def instance_text_scores(self, text_embedding: np.ndarray) -> np.ndarray:
        """(I,) float32 per-instance text similarity (``clutt3r_core.query.instance_text_scores``)."""
        from clutt3r_core.query import instance_text_scores

        return instance_text_scores(self.seg, text_embedding)


def _vote_config(tr: Trace) -> VoteConfig:
    return tr.config.vote  # typed; load_trace refuses a config it cannot read back exactly


def node_label(tr: Trace, i: int) -> str:
    """'F{frame} M{mask}' for node i."""
    return f"F{int(tr.nodes.frame[i])} M{int(tr.nodes.mask_id[i])}"


def _group_label(tr: Trace, g: tuple[int, ...], limit: int = 4) -> str:
    names = [node_label(tr, i) for i in g[:limit]]
    more = f" +{len(g) - limit}" if len(g) > limit else ""
    return "{" + ", ".join(names) + more + "}"


def event_text(tr: Trace, n: int) -> str:
    """Markdown for event n (1-based: the n-th event, the one that leads to groups_at(n))."""
    events = tr.grouping.events
    if n <= 0 or not events:
        return f"**start**: every non-background leaf alone ({len(events)} events follow)"
    kind, idx = events[min(n, len(events)) - 1]
    if kind == "merge":
        m = tr.grouping.merges[idx]
        return (
            f"**{n}/{len(events)} merge**, stage {m.stage}, round {m.round}, score {m.score:.3f}  \n"
            f"{_group_label(tr, m.a)} + {_group_label(tr, m.b)}  \n"
            f"S_spatial {m.spatial:.3f}, S_semantic {m.semantic:.3f}"
        )
    s = tr.grouping.substitutions[idx]
    return (
        f"**{n}/{len(events)} substitution**, round {s.round}: parent {node_label(tr, s.parent)} "
        f"replaces residual {', '.join(node_label(tr, r) for r in s.replaced)}"
    )


def build_viewer_data(
    seg: Segmentation,
    scene: Scene | None = None,
    grasps: GraspSet | None = None,
    updates: tuple[UpdateFrame, ...] = (),
) -> ViewerData:
    """Derive everything the viewer needs from a segmentation (and its scene, for images)."""
    tr = seg.trace
    nodes = tr.nodes
    u = len(nodes)
    k = len(seg.sv_support)
    lab = seg.sv_labels.astype(np.int64)
    counts = seg.counts.astype(np.float64)
    sv_count = np.bincount(lab, weights=counts, minlength=k)
    sv_centroid = np.stack(
        [np.bincount(lab, weights=counts * seg.points[:, d], minlength=k) for d in range(3)], axis=1
    ) / np.maximum(sv_count, 1e-12)[:, None]
    w = tr.occupancy.astype(np.float64) * sv_count[None, :]
    wsum = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        node_centroid = (w @ sv_centroid) / wsum[:, None]
    node_centroid[wsum <= 0] = np.nan

    node_group = np.full(u, -1, np.int32)
    for gi, g in enumerate(tr.grouping.groups):
        node_group[list(g)] = gi
    node_instance = np.full(u, -1, np.int32)
    for inst, gi in enumerate(tr.vote.instance_group):
        node_instance[list(tr.grouping.groups[int(gi)])] = inst
    substituted = np.zeros(u, bool)
    replaced = np.zeros(u, bool)
    for s in tr.grouping.substitutions:
        substituted[s.parent] = True
        replaced[list(s.replaced)] = True
    sizes = np.array([len(g) for g in tr.grouping.groups] or [0])
    residual = nodes.is_leaf & ~nodes.background & ((node_group < 0) | (sizes[np.maximum(node_group, 0)] == 1))
    residual |= replaced

    active = np.flatnonzero(nodes.is_leaf & ~nodes.background)
    if len(active) > 1:
        ii, jj = np.triu_indices(len(active), 1)
        a, b = active[ii], active[jj]
        sp = tr.s_spatial[a, b]
        se = tr.s_semantic[a, b]
        keep = (nodes.view[a] != nodes.view[b]) & (np.isfinite(sp) | np.isfinite(se))
        edges = np.stack([a[keep], b[keep]], axis=1).astype(np.int64)
        edge_sp, edge_se = sp[keep].astype(np.float32), se[keep].astype(np.float32)
    else:
        edges = np.zeros((0, 2), np.int64)
        edge_sp = edge_se = np.zeros(0, np.float32)

    views: tuple[View, ...] = ()
    if scene is not None:
        try:
            views = tuple(scene.view_by_frame(int(f)) for f in tr.frames)
        except KeyError as e:
            raise SceneError(f"scene {scene.name or scene.root} does not match the run: {e}") from None
    return ViewerData(
        seg=seg, views=views, sv_count=sv_count, sv_centroid=sv_centroid, node_centroid=node_centroid,
        node_group=node_group, node_instance=node_instance, residual=residual, substituted=substituted,
        replaced=replaced, edges=edges, edge_spatial=edge_sp, edge_semantic=edge_se, grasps=grasps,
        updates=tuple(updates), scene_root=None if scene is None else scene.root,
    )
