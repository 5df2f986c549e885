"""The segmentation pipeline (Sec. III-A, III-B): scene -> 3D instances with a full trace.

``segment(scene, config)`` runs, on the scene's initial views:
mask candidates where the scene has none (``masks.ensure_candidates``: the builtin generator by
default, issue 11) -> point cloud fusion -> super-voxels -> per-view instance trees -> node occupancy and
embeddings -> leaf graph -> two-stage grouping with substitution -> super-voxel
majority vote. A run folder is written and read by ``clutt3r_core.runs`` (``save_run`` /
``load_run``, re-exported here); the config and its presets live in ``clutt3r_core.config``
(re-exported here); the ``clutt3r segment`` command is ``clutt3r_core.commands.segment``.
"""

from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from clutt3r_core.config import PRESETS, SegmentConfig, _paper_literal  # noqa: F401  (re-exported)
from clutt3r_core.diagnostics import RunWarning, check_usable_depth, view_warnings
from clutt3r_core.embeddings import MaskEmbedder, create_embedder
from clutt3r_core.errors import SceneError
from clutt3r_core.masks import MaskGenerator, MaskProvenance, ensure_candidates
from clutt3r_core.occupancy import mask_occupancy, mask_voxel_hits
from clutt3r_core.pointcloud import fuse_views
from clutt3r_core.rim import attach_labels
from clutt3r_core.runs import load_run, save_run  # noqa: F401  (re-exported)
from clutt3r_core.scene import MaskCandidates, Scene
from clutt3r_core.segmentation.evidence import background_masks, check_views
from clutt3r_core.segmentation.duplicates import duplicate_masks
from clutt3r_core.segmentation.grouping import (
    NodeTable,
    SimilarityGraph,
    run_grouping,
    reunion_weights,
    semantic_similarity,
    spatial_similarity,
)
from clutt3r_core.segmentation.instance_surface import smooth_instances
from clutt3r_core.segmentation.contact_masks import mask_views
from clutt3r_core.segmentation.refine import absorb_fragments, contact_labels, labels_before_contact
from clutt3r_core.segmentation.span import cleared_occupancy, span_revote, unique_pairs
from clutt3r_core.segmentation.trace import StageClock, StageTiming, Trace
from clutt3r_core.segmentation.trees import InstanceTree, build_tree_overlaps
from clutt3r_core.segmentation.unvoted import unvoted_instances
from clutt3r_core.segmentation.vote import supervoxel_vote
from clutt3r_core.supervoxels import build_supervoxels
from clutt3r_core.support import kept_spatial, planar_covered

__all__ = [
    "SegmentConfig",
    "PRESETS",
    "Segmentation",
    "segment",
    "save_run",
    "load_run",
    "instance_tree_json",
]


@dataclass(frozen=True, eq=False)
class Segmentation:
    """3D instances of a scene and the trace that produced them.

    Attributes:
        points: (N, 3) float32 world metres (fused voxel centres); the last ``trace.surface.rim``
            are the fusion's rim voxels, labelled after the vote (``clutt3r_core.rim``).
        colors: (N, 3) uint8.
        normals: (N, 3) float32 unit.
        counts: (N,) int32 raw points per voxel.
        instance: (N,) int32 instance id per point, -1 = none; ids 0..K-1 by descending score.
        scores: (K,) float32 instance confidences.
        sv_labels: (N,) int32 super-voxel of each point.
        sv_support: (Ks,) bool support flag per super-voxel.
        trace: every intermediate (segmentation/trace.py).
        scene_name: name of the scene.
        warnings: what degraded the input (``diagnostics.RunWarning``): the loader's and the
            view checks'; recorded in run.json.
        masks: where the mask candidates came from (``masks.MaskProvenance``: the scene's own,
            or a generator's, which ``save_run`` writes to RUN/instance_masks/); run.json ``masks``.
    """

    points: np.ndarray
    colors: np.ndarray
    normals: np.ndarray
    counts: np.ndarray
    instance: np.ndarray
    scores: np.ndarray
    sv_labels: np.ndarray
    sv_support: np.ndarray
    trace: Trace
    scene_name: str = ""
    warnings: tuple[RunWarning, ...] = ()
    masks: MaskProvenance = MaskProvenance()

    def __post_init__(self) -> None:
        object.__setattr__(self, "warnings", tuple(self.warnings))
        if not isinstance(self.masks, MaskProvenance):
            raise SceneError("Segmentation.masks must be a masks.MaskProvenance")
        if not all(isinstance(w, RunWarning) for w in self.warnings):
            raise SceneError("Segmentation.warnings must hold diagnostics.RunWarning values")
        n = self.points.shape[0]
        if self.points.shape != (n, 3) or self.colors.shape != (n, 3) or self.instance.shape != (n,):
            raise SceneError("Segmentation: points (N,3), colors (N,3) and instance (N,) must agree")
        k = len(self.scores)
        if n and (self.instance.min() < -1 or self.instance.max() >= k):
            raise SceneError(f"Segmentation: instance ids must lie in -1..{k - 1}")

    @property
    def num_instances(self) -> int:
        return len(self.scores)

    def instance_nodes(self, k: int) -> tuple[int, ...]:
        """Node indices (into trace.nodes) of the masks that make instance k; () for an instance
        the unvoted-cluster fallback added (``segmentation.unvoted``: ids after the voted ones)."""
        if not 0 <= k < self.num_instances:
            raise IndexError(f"instance {k} out of range 0..{self.num_instances - 1}")
        if k >= len(self.trace.vote.instance_group):
            return ()
        return self.trace.grouping.groups[int(self.trace.vote.instance_group[k])]


def segment(
    scene: Scene,
    config: SegmentConfig = SegmentConfig(),
    embedder: MaskEmbedder | None = None,
    progress: bool = False,
    masks: str | MaskGenerator = "auto",
) -> Segmentation:
    """Segment the initial views of ``scene`` into 3D instances (Sec. III-A, III-B).

    ``masks``: where the mask candidates come from (``masks.ensure_candidates``): ``"auto"``
    keeps the scene's own and gives views without any the builtin generator's; ``"scene"``
    refuses a view without candidates (``SceneError``); a generator name or object replaces
    every initial view's. Recorded in ``Segmentation.masks`` (and by ``save_run``).

    numpy's BLAS runs on one thread for the call (threadpoolctl; restored after): every
    product here is small, where OpenBLAS's worker threads only spin (issue 13: 0.6-1 s of
    CPU of ~3 on a hard 640x480 scene, identical results).

    The instance trees and a light embedder's embeddings (``beside_fusion``, the builtin
    appearance one) are computed on a second thread while the point cloud is fused and
    clustered; an embedder without that attribute runs in turn, after the occupancy.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        return _segment(scene, config, embedder, progress, masks)


def _segment(scene: Scene, config: SegmentConfig, embedder: MaskEmbedder | None, progress: bool,
             masks: str | MaskGenerator) -> Segmentation:
    check_views(scene, masks=False)  # a view without depth: that error, not the generator's
    scene, provenance = ensure_candidates(scene, masks, progress=progress)
    check_views(scene)
    timer = StageClock()
    if provenance.generated:  # generation is part of the run's cost; absent when nothing was made
        timer.items.append(StageTiming("masks", provenance.seconds))
    embedder = embedder or create_embedder(config.embedder)
    # canonical view order (by frame) so that the result does not depend on input order
    views = sorted(scene.initial_views, key=lambda v: v.frame)
    bar = None
    if progress:
        from tqdm import tqdm

        # disable=None: no bar when stderr is not a terminal (a log file gets no bar fragments)
        bar = tqdm(total=6, desc=f"segment {scene.name}", unit="stage", leave=False, disable=None)
        bar.set_postfix_str("pointcloud")

    def tick(next_stage: str) -> None:
        if bar is not None:
            bar.update(1)
            bar.set_postfix_str(next_stage)

    def build_trees():
        built = [build_tree_overlaps(v.masks, v.frame, config.trees) for v in views]
        trees = tuple(t for t, _ in built)
        return (built, trees, *_node_table(views, trees))

    def embed(nodes_masks) -> np.ndarray:
        # compact candidates where the embedder takes them, else one view's stack at a time
        compact = getattr(embedder, "accepts_candidates", False)
        emb = [embedder.embed_masks(v.rgb, m if compact else m.stack()) for v, m in zip(views, nodes_masks)]
        return np.concatenate(emb, axis=0).astype(np.float32) if emb else np.zeros((0, 1), np.float32)

    def beside_fusion() -> tuple:
        """Trees and embeddings (they need only the views) with their wall seconds."""
        t0 = time.perf_counter()
        tr = build_trees()
        t1 = time.perf_counter()
        return tr, embed(tr[2]), t1 - t0, time.perf_counter() - t1

    def all_hits(beside, cloud) -> tuple:
        """Every view's ``mask_voxel_hits`` (the trees' candidate order) and this thread's CPU
        seconds for them (its wall seconds would count the wait for a core while the super-voxels
        run: about its CPU on a machine with a free core, twice that on a busy one)."""
        nodes_masks = beside.result()[0][2]  # done: this pool's one thread ran it first
        t0 = time.thread_time()
        return [mask_voxel_hits(cloud, vi, m) for vi, m in enumerate(nodes_masks)], time.thread_time() - t0

    # ours (issue 13): a light embedder (``beside_fusion``) and the trees it needs run on a
    # second thread while the point cloud is fused and clustered (mostly one thread): the same
    # calls on the same inputs, so the same results; their timings are their own wall seconds,
    # listed where the stages were
    pool = ThreadPoolExecutor(1) if getattr(embedder, "beside_fusion", False) else None
    beside = pool.submit(beside_fusion) if pool is not None else None
    try:
        with timer("pointcloud"):
            cloud = fuse_views(views, config.pointcloud)
        try:
            check_usable_depth(views, cloud, config.pointcloud)
        except SceneError:
            if bar is not None:  # clear the bar before the error is printed, not after it
                bar.close()
            raise
        # the loader's own (e.g. a frame demoted to post-interaction), then what the fusion shows
        warnings = tuple(scene.warnings) + view_warnings(views, cloud, config.pointcloud)
        # ours (issue 13): each view's mask hits per voxel need only the cloud and the trees, so
        # the second thread counts them (after the trees and embeddings) while the super-voxels
        # are built here; the same calls on the same inputs
        hits_beside = pool.submit(all_hits, beside, cloud) if pool is not None else None
        tick("supervoxels")
        with timer("supervoxels"):
            sv = build_supervoxels(cloud, config.supervoxels)
        tick("trees")
        if beside is not None:
            (built, trees, nodes_masks, nodes), embeddings, t_trees, t_emb = beside.result()  # re-raises its error
            timer.items.append(StageTiming("trees", t_trees))
            view_hits, t_hits = hits_beside.result()
        else:
            with timer("trees"):
                built, trees, nodes_masks, nodes = build_trees()
    finally:
        if pool is not None:  # after an error above, the thread's work finishes and is dropped
            pool.shutdown(wait=True)
    tick("occupancy")

    with timer("occupancy"):
        if beside is None:
            view_hits, t_hits = [mask_voxel_hits(cloud, vi, m) for vi, m in enumerate(nodes_masks)], 0.0
        occ_parts, bg_parts = [], []
        support_voxel = sv.support[sv.labels]
        for vi, (v, masks) in enumerate(zip(views, nodes_masks)):
            hits = view_hits[vi]  # once per view: occupancy and background
            occ_parts.append(mask_occupancy(cloud, sv, vi, masks, config.occupancy, hits=hits))
            bg_parts.append(background_masks(hits, support_voxel, config.background_fraction)
                            if config.exclude_background_masks else np.zeros(len(masks), bool))
        occupancy = np.concatenate(occ_parts, axis=0) if occ_parts else np.zeros((0, sv.num), np.float32)
        background = np.concatenate(bg_parts) if bg_parts else np.zeros(0, bool)
        share = config.supervoxels.planar_mask_views
        first_support, first_object = sv.support, ~background  # before any un-marking
        if share > 0 and sv.planar is not None and sv.planar.any() and len(background):
            # ours (sessions 9-10; ``planar-tops``): rule 3's planar support that object masks cover
            # in most views is an object's flat top (``support.planar_covered``); the masks'
            # background flags are first taken without that support, then again without it; the
            # leaf edges of the masks admitted the first time stay theirs (``support.kept_spatial``)
            core_voxel = (sv.support & ~sv.planar)[sv.labels]
            obj = ~np.concatenate([background_masks(h, core_voxel, config.background_fraction) for h in view_hits])
            visible = np.stack([np.bincount(sv.labels[cloud.pixel_voxel.pixels(vi)[1]], minlength=sv.num) > 0
                                for vi in range(len(views))])
            unmark = planar_covered(sv.planar, occupancy, nodes.view, obj, visible, share)
            if unmark.any():
                sv = dataclasses.replace(sv, support=sv.support & ~unmark, planar=sv.planar & ~unmark)
                if config.exclude_background_masks:
                    support_voxel = sv.support[sv.labels]
                    background = np.concatenate([background_masks(h, support_voxel, config.background_fraction)
                                                 for h in view_hits])
        # ours (issue 13): near-identical masks of one view are one mask (segmentation/duplicates.py)
        # (from the pixel overlaps the trees counted: no pixel is visited again)
        dups = duplicate_masks(nodes.view, nodes.parent, nodes.is_leaf, background, [o for _, o in built],
                               config.grouping.duplicate_iou, config.trees.tau_contain)
        nodes = NodeTable(nodes.frame, nodes.view, nodes.mask_id, nodes.parent, nodes.is_leaf & ~dups.shadow,
                          background)
    if t_hits:  # the stage's time: here, plus the hits' CPU seconds on the second thread
        timer.items[-1] = StageTiming("occupancy", timer.items[-1].seconds + t_hits)
    tick("embeddings + leaf graph")

    if beside is not None:
        timer.items.append(StageTiming("embeddings", t_emb))
    else:
        with timer("embeddings"):
            embeddings = embed(nodes_masks)

    with timer("leaf_graph"):
        # support super-voxels carry no evidence of object identity (findings point 4)
        if not config.grouping.spatial_excludes_support:
            s_spat = spatial_similarity(occupancy, sv.weights)
        else:
            # the masks the un-marking re-admitted link over the un-marked super-voxels; those the
            # default admitted keep the edges it gave them (``support.kept_spatial``; ours, session 10)
            s_spat = kept_spatial(occupancy, sv.weights, sv.support, first_support, first_object)
        s_sem = semantic_similarity(embeddings)
        no_edge = nodes.view[:, None] == nodes.view[None, :]
        no_edge |= background[:, None] | background[None, :]
        s_spat[no_edge] = np.nan
        s_sem[no_edge] = np.nan
        sim = SimilarityGraph(s_spat, s_sem)
    tick("grouping + vote")

    with timer("grouping"):
        grouping = run_grouping(nodes, sim, len(views), config.grouping, duplicates=dups.pairs,
                                overlaps=[o for _, o in built])
    with timer("vote"):
        # the reunion's confidence weights: only its own merges set them, so the absorption's later
        # merges leave them as they are (``grouping.reunion_weights``)
        mask_weight = reunion_weights(grouping.merges, nodes.view) if config.grouping.reunion_tau > 0 else None

        def revote(groups, occ=occupancy):
            return supervoxel_vote(groups, occ, sv.counts, sv.support, s_spat, len(views), config.vote, mask_weight)

        vote = revote(grouping.groups)
        occ_vote, pre_cleared = occupancy, None
        if config.vote.span_cover > 0 and config.vote.span_before_absorb:
            # ours (session 10, off): the spanning masks' votes are cleared before the absorption
            # too, so that a neighbour's spanning masks do not absorb the object they span
            g0 = grouping.groups
            vote = span_revote(g0, occupancy, sv.counts, sv.support, vote, lambda occ: revote(g0, occ),
                               config.vote, nodes.view, len(views))
            pre_cleared = vote.span_cleared
            occ_vote = cleared_occupancy(occupancy, pre_cleared)
        # ours (issue 13): fragment groups join the instance that won their masks' footprint
        grouping, vote = absorb_fragments(grouping, vote, occ_vote, sv.counts, s_spat, s_sem,
                                          lambda g: revote(g, occ_vote), config.refine)
        if config.vote.span_cover > 0:
            # ours (session 9; 0 = off): a mask spanning another group's footprint, unconfirmed
            # by its own group, does not vote there (``segmentation.span``); after the absorption, so
            # that a fragment of the mask's own object has joined its group first
            groups = grouping.groups
            vote = span_revote(groups, occ_vote, sv.counts, sv.support, vote, lambda occ: revote(groups, occ),
                               config.vote, nodes.view, len(views))
            if pre_cleared is not None and len(pre_cleared):
                vote = dataclasses.replace(vote, span_cleared=unique_pairs([pre_cleared, vote.span_cleared], sv.num))
        # the vote's labels per voxel; ours, off by default: small super-voxels smoothed (session 8),
        # weak echoes unlabelled (issue 13). One function, so that the labels the contact rule
        # changes can be recomputed from a run (``refine.run_labels_before_contact``)
        instance = labels_before_contact(vote.sv_label, sv.labels, sv.support, cloud.points, cloud.normals,
                                         cloud.counts, config.pointcloud.voxel_size, config.vote, config.refine)
    scores = vote.scores
    if config.unvoted.min_points > 0:
        # ours (session 8), off by default: unlabelled clusters standing above the support (no
        # candidate mask covered them) become instances after, and below, every voted one
        with timer("unvoted"):
            bg_cover = (occupancy[background].max(axis=0) if background.any()
                        else np.zeros(occupancy.shape[1], np.float32))
            unv = unvoted_instances(cloud.points, cloud.counts, instance, sv.labels, sv.support, bg_cover, sv.plane,
                                    vote.scores, config.unvoted)
            instance, scores = unv.instance, unv.scores
    points, colors, normals, counts, sv_labels = cloud.points, cloud.colors, cloud.normals, cloud.counts, sv.labels
    if cloud.rim is not None:
        # ours (issue 13): the rim voxels the fusion kept apart take their segmented neighbours'
        # majority label and join the super-voxel of the nearest voter with it; appended last
        # (``SurfaceChoice.rim`` of them), so every index into the segmented cloud stays valid
        with timer("attach"):
            rim = cloud.rim
            att = attach_labels(cloud.points, instance, rim.points, config.pointcloud.surface_rim_attach_k,
                                config.pointcloud.surface_rim_attach_distance)
            instance = np.concatenate([instance, att.label])
            sv_labels = np.concatenate([sv.labels, sv.labels[att.source]])
            points, colors = np.concatenate([points, rim.points]), np.concatenate([colors, rim.colors])
            normals, counts = np.concatenate([normals, rim.normals]), np.concatenate([counts, rim.counts])
    if cloud.surface is not None and cloud.surface.method == "tsdf":
        # ours (issue 13): on noisy depth (the fusion ran the surface estimate) the object-support
        # contact is relabelled by height above each object's own support level: the lowest walls
        # the support rule took are the object's, its lowest millimetres the table's
        # (``refine.contact_labels``; on clean depth it cost AP50)
        r = config.refine
        mviews = None
        if r.contact_fill_mask_share > 0 and r.contact_fill_high > r.contact_fill_low:
            # ours (session 9), off by default: the fill's candidates are tested against the masks
            # of the instance they would join (``segmentation.contact_masks``)
            node_inst = np.full(len(nodes.view), -1, np.int64)
            for k, gi in enumerate(vote.instance_group):
                node_inst[list(grouping.groups[int(gi)])] = k
            mviews = mask_views([v.camera for v in views], [v.depth for v in views], nodes_masks, nodes.view,
                                node_inst, len(scores))
        instance = contact_labels(points, normals, instance, len(scores), sv.plane, r, mviews).instance
    if config.instance_surface.enabled:
        # ours (issue 13), off by default: each instance's points onto a local surface fitted to its
        # own points only (never averaged across a contact); labels, counts and normals stay
        with timer("instance_surface"):
            points = smooth_instances(points, instance, config.instance_surface, counts,
                                      config.pointcloud.voxel_size).points
    tick("done")
    if bar is not None:
        bar.close()

    trace = Trace(
        frames=np.array([v.frame for v in views], np.int32),
        trees=trees,
        nodes=nodes,
        embeddings=embeddings,
        occupancy=occupancy.astype(np.float32),
        s_spatial=s_spat,
        s_semantic=s_sem,
        grouping=grouping,
        vote=vote,
        timings=tuple(timer.items),
        embedder=getattr(embedder, "name", type(embedder).__name__),
        config=config,
        surface=cloud.surface,
    )
    return Segmentation(
        points=points,
        colors=colors,
        normals=normals,
        counts=counts,
        instance=instance.astype(np.int32),
        scores=scores,
        sv_labels=sv_labels,
        sv_support=sv.support,
        trace=trace,
        scene_name=scene.name,
        warnings=warnings,
        masks=provenance,
    )


def _node_table(views, trees: tuple[InstanceTree, ...]) -> tuple[list[MaskCandidates], NodeTable]:
    """Nodes in canonical order (view by frame, mask by id) and each view's mask candidates in
    that order (``MaskCandidates.select``: the view's code image is shared, not copied)."""
    frame, view, mask_id, parent, is_leaf, stacks = [], [], [], [], [], []
    offset = 0
    for vi, (v, t) in enumerate(zip(views, trees)):
        m = len(t.mask_ids)
        idx = np.array([v.masks.index_of(int(i)) for i in t.mask_ids], np.int64)
        stacks.append(v.masks if np.array_equal(idx, np.arange(len(v.masks))) else v.masks.select(idx))
        frame.append(np.full(m, v.frame, np.int32))
        view.append(np.full(m, vi, np.int32))
        mask_id.append(t.mask_ids.astype(np.int32))
        parent.append(np.where(t.parent >= 0, t.parent + offset, -1).astype(np.int32))
        is_leaf.append(t.is_leaf)
        offset += m
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    nodes = NodeTable(
        frame=cat(frame, np.int32), view=cat(view, np.int32), mask_id=cat(mask_id, np.int32),
        parent=cat(parent, np.int32), is_leaf=cat(is_leaf, bool), background=np.zeros(offset, bool),
    )
    return stacks, nodes


def instance_tree_json(seg: Segmentation) -> dict:
    """The grouping in the original release's schema (schema_version 1).

    ``initial.leaf2inst`` lists every tree leaf of the initial frames with the instance
    it ended in (-1 if its group did not become an instance, e.g. background masks).
    A residual leaf that was substituted by its parent (Sec. III-B.3) is written with
    the instance of the parent's group; the substituted parents themselves are listed
    under ``clutt3r.substituted_parents``. Our extra data lives under the ``clutt3r`` key.
    """
    tr = seg.trace
    n = tr.nodes
    node_inst = tr.node_instance(follow_substitutions=True)
    leaf2inst = [
        {"frame": int(n.frame[i]), "mask": int(n.mask_id[i]), "instance": int(node_inst[i])}
        for i in np.flatnonzero(n.is_leaf)
    ]
    return {
        "schema_version": 1,
        "source": "Clutt3R (this project): hierarchy-based grouping re-implemented from the paper.",
        "initial": {"initial_idx": [int(f) for f in tr.frames], "leaf2inst": leaf2inst},
        "updates": {},
        "clutt3r": {
            "embedder": tr.embedder,
            "substituted_parents": [
                {"frame": int(n.frame[s.parent]), "mask": int(n.mask_id[s.parent]),
                 "instance": int(node_inst[s.parent]),
                 "replaced": [int(n.mask_id[r]) for r in s.replaced]}
                for s in tr.grouping.substitutions
            ],
            "background_masks": [
                {"frame": int(n.frame[i]), "mask": int(n.mask_id[i])} for i in np.flatnonzero(n.background)
            ],
        },
    }
