"""Which of a run's points are an object's geometry: what an update moves and a grasp targets.

The labels a run shows (``seg.instance``, the Edit tab) are those after the rules that trim them
for the segmentation's score (``refine.contact_labels``: on noisy depth each object's lowest ~2 mm
unlabelled). Consumers of an object's whole extent read the labels before those rules instead:
the update's state (``state.state_from_segmentation``: which points move and leave with their
instance), the grasp target at step 0 (``run_labels.StepZeroLabels.geometry``) and after updates
(``scene_after.chain_inputs``, the viewer's ``scene_step.chain_inputs_of``). ``geometry_labels``
is the one mapping all of them call, in the run's own ids or in a corrected labelling's
(``corrected_geometry_labels``: the trimmed points follow their instance through the Edit tab's
merges and splits). ``held_geometry`` tells whether a saved chain's state holds that geometry (a
chain computed by an older version keeps the one labelling it was computed with).
"""

from __future__ import annotations

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["fused_count", "corrected_geometry_labels", "geometry_labels", "held_geometry", "state_rows"]


def fused_count(seg) -> int:
    """Points of a run's cloud (``pipeline.Segmentation``) that are fused voxels: all but the
    fusion's rim voxels, its last ``trace.surface.rim`` points (``clutt3r_core.rim``; 0 with the
    voxel-mean fusion and in older traces). The update's state holds these (``state_from_segmentation``)."""
    surface = seg.trace.surface  # Trace.surface: None with the voxel-mean fusion and in older traces
    return len(seg.points) - (surface.rim if surface is not None else 0)


def corrected_geometry_labels(seg, corrected: np.ndarray, n: int, pre: np.ndarray | None = None) -> np.ndarray:
    """(n,) int32: the corrected labels of the run's first n points, with the points the contact rule
    cleared (labelled before it, unlabelled in the run and left unlabelled by the corrections) given
    the corrected id of the nearest point of their own pre-contact instance that has one. A merge
    carries them to the merged id, a split to the nearer part; a deleted instance keeps them
    unlabelled (none of its points has an id). Without this a correction brought the contact's
    labels back into the update's geometry (``state._geometry_labels``: the moved clamp read
    static) and into the grasp target (``StepZeroLabels.geometry``). The points the contact fill
    labelled (unlabelled before the rule) are left unlabelled, as in ``run_labels_before_contact``.

    Where the nearest point is searched: a fused point (the first ``fused_count(seg)``) among the
    fused points only, as the update's state maps them (it holds no rim voxel), so its first rows
    are the state's labels whatever ``n``; a rim voxel among the first n points (fused or rim,
    the nearer). One search per cleared point: step 0 (``StepZeroLabels.geometry``), the state
    (``state.state_from_segmentation``) and the scenes after updates (``geometry_labels``) read
    this one mapping (session 9: with the rim voxels searched for fused points too, one fused
    point of a split on generated easy seed 11 was I3 at step 0 and I2 in the state).

    ``pre``: ``refine.run_labels_before_contact(seg)`` when already computed (the viewer keeps it)."""
    if pre is None:
        from clutt3r_core.segmentation.refine import run_labels_before_contact

        pre = run_labels_before_contact(seg)
    out = np.array(corrected[:n], np.int32)
    pre = np.asarray(pre)[:n]
    run = np.asarray(seg.instance[:n])
    # the points the contact fill labelled (unlabelled before the rule) are not the geometry's either,
    # whatever id a correction gave them (``refine.contact_labels``; off by default, on with ``contact_fill_low`` / ``_high``)
    out[(pre < 0) & (run >= 0)] = -1
    cleared = (pre >= 0) & (run < 0) & (out < 0)
    if not cleared.any():
        return out
    from scipy.spatial import cKDTree

    pts = np.asarray(seg.points[:n])
    f = min(fused_count(seg), n)
    for k in np.unique(pre[cleared]):
        src = np.flatnonzero((pre == k) & (out >= 0))
        dst = np.flatnonzero(cleared & (pre == k))
        src_f, src_r = src[src < f], src[src >= f]
        dst_f, dst_r = dst[dst < f], dst[dst >= f]
        tree = cKDTree(pts[src_f]) if len(src_f) else None
        if tree is not None and len(dst_f):
            out[dst_f] = out[src_f[tree.query(pts[dst_f])[1]]]
        if len(dst_r) and len(src):
            # a rim voxel: the nearer of the nearest fused source and the nearest rim source
            d_f, i_f = tree.query(pts[dst_r]) if tree is not None else (np.full(len(dst_r), np.inf), None)
            best = src_f[i_f] if tree is not None else np.zeros(len(dst_r), np.int64)
            if len(src_r):
                d_r, i_r = cKDTree(pts[src_r]).query(pts[dst_r])
                best = np.where(d_r < d_f, src_r[i_r], best)
            out[dst_r] = out[best]
    return out


def geometry_labels(seg, instance: np.ndarray | None = None, pre: np.ndarray | None = None,
                    corrected: bool | None = None) -> np.ndarray:
    """(N,) int32 the labels before the contact rule of a run's whole cloud (rim voxels included) in
    the ids of a labelling ``instance`` ((N,) int, None: the run's own): the ONE mapping of step 0's
    grasp target (``StepZeroLabels.geometry``), the update state's labels (its fused rows) and the
    scenes after updates (``scene_after.chain_inputs``, the viewer's ``scene_step.chain_inputs_of``).

    The run's own ids: ``refine.run_labels_before_contact(seg)`` (``pre``: it, when already computed).
    Corrected ids: ``corrected_geometry_labels`` over the whole cloud (a fused point mapped among the
    fused points, as the state maps it). ``corrected``: whether the labelling is a corrected one (a
    chain: its state's "labels" record has log entries); None: when ``instance`` differs from the
    run's labels."""
    if pre is None:
        from clutt3r_core.segmentation.refine import run_labels_before_contact

        pre = run_labels_before_contact(seg)
    inst = np.asarray(seg.instance if instance is None else instance, np.int32)
    if len(inst) != len(seg.points) or len(pre) != len(seg.points):
        raise SceneError(f"geometry labels: labels of {len(inst)} / {len(pre)} points for a run of {len(seg.points)}")
    if corrected is None:
        corrected = not np.array_equal(inst, seg.instance)
    if not corrected:
        return np.array(pre, np.int32)
    return corrected_geometry_labels(seg, inst, len(inst), pre)


def held_geometry(geo: np.ndarray, seg, removed, rows: np.ndarray | str) -> np.ndarray | None:
    """``geo`` when a saved state's run rows are the run's fused points labelled ``geo`` less the
    removed instances' (``state.apply_update`` keeps the order and drops by these labels): the
    state's own geometry, exactly; else None (a chain computed by an older version: its state reads
    the contact rule's labels or an earlier recompute of the labels before it, and its scene is the
    one it always was, one labelling). The one decision ``chain_inputs`` and the viewer's
    ``scene_step.chain_inputs_of`` make, O(N).

    ``rows``: the state's labels less the added instances', in order ((M,) int), or their
    ``run_labels.labels_sha256`` (the viewer's loader keeps the digest, ``UpdateFrame.state_rows_sha256``)."""
    from clutt3r_core.update.run_labels import labels_sha256

    g = geo[:fused_count(seg)]
    kept = g[~(np.isin(g, list(removed)) & (g >= 0))]
    same = labels_sha256(kept) == rows if isinstance(rows, str) else np.array_equal(kept, rows)
    return geo if same else None


def state_rows(instance: np.ndarray, added) -> np.ndarray:
    """(M,) the run rows of a saved state's labels ``instance``: less the points of the ids the
    chain's updates added (``added``, those removed since included), in order (``held_geometry``)."""
    instance = np.asarray(instance)
    return instance[~np.isin(instance, list(added))]
