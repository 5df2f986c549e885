"""Which of a run's points are an object's geometry: what an update moves and a grasp targets.

The labels a run shows (``seg.instance``, the Edit tab) are those after the rules that trim them
for the segmentation's score: weak echoes unlabelled (``refine.weak_echoes``, off by default) and,
on noisy depth, each object's lowest ~2 mm unlabelled (``refine.contact_labels``). Consumers of an
object's whole extent read ``run_geometry`` instead: the labels before both rules, plus the points
the contact fill gave an object (off by default). They are the update's state
(``state.state_from_segmentation``: which points move and leave with their instance), the grasp
target at step 0 (``run_labels.StepZeroLabels.geometry``, ``grasping.request``) and after updates
(``scene_after.chain_inputs``, the viewer's ``scene_step.chain_inputs_of``). ``geometry_labels``
is the one mapping all of them call, in the run's own ids or in a corrected labelling's
(``corrected_geometry_labels``: the trimmed points follow their instance through the Edit tab's
merges and splits). ``held_geometry`` tells whether a saved chain's state holds that geometry (a
chain computed by an older version keeps the one labelling it was computed with).
"""

from __future__ import annotations

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["fused_count", "run_geometry", "corrected_geometry_labels", "geometry_labels", "held_geometry", "state_rows"]


def fused_count(seg) -> int:
    """Points of a run's cloud (``pipeline.Segmentation``) that are fused voxels: all but the
    fusion's rim voxels, its last ``trace.surface.rim`` points (``clutt3r_core.rim``; 0 with the
    voxel-mean fusion and in older traces). The update's state holds these (``state_from_segmentation``)."""
    surface = seg.trace.surface  # Trace.surface: None with the voxel-mean fusion and in older traces
    return len(seg.points) - (surface.rim if surface is not None else 0)


def run_geometry(seg) -> np.ndarray:
    """(N,) int32 the run's own ids of its whole cloud (rim voxels included) as objects' geometry,
    -1 = none: the labels before the two rules that trim the shown labels, with the fill's points.

    - Weak echoes (``refine.weak_echo_ratio`` > 0, off by default): the flanks the rule unlabels are
      depth noise spilling off the object's own surface; the planner counted them as foreign points
      between the fingers (generated easy seed 0 at ratio 0.2: grasps per instance 31 / 5 / 4 / 2 with
      the rule off, 12 / 0 / 0 / 0 with it on; docs/corrections.md, session 10) and an update left
      them behind. Here they keep the vote's label: the segmented cloud's labels with the ratio 0
      (``refine.labels_before_contact``), the rim voxels attached to those again (``rim.attach_labels``
      with the run's settings) and the instances added after the vote (``segmentation.unvoted``)
      as the run has them: the labels the run held before both rules, which a run segmented with
      the echo rule off holds before the contact rule (tests/core/update/test_geometry_rules.py).
    - The contact (``refine.contact_height``): the cleared points keep their label
      (``refine.run_labels_before_contact``, as before).
    - The contact fill (``refine.contact_fill_low`` / ``_high``, off by default): the points it
      labelled (unlabelled before the rule, an object's in the run) ARE that object's: walls the
      support rule took, confirmed by its masks (``contact_fill_mask_share``). They are its
      geometry, so they move and leave with it and are part of its grasp target (until session 10 a
      displaced object's filled walls stayed behind, unlabelled). A point the vote labelled (echo
      cleared, then filled with another object) keeps the vote's label.

    Default config (echoes and fill off): ``refine.run_labels_before_contact(seg)`` exactly."""
    from clutt3r_core.segmentation.refine import run_labels_before_contact

    refine = seg.trace.config.refine
    inst = np.asarray(seg.instance)
    pre = None
    if refine.weak_echo_ratio <= 0 or refine.contact_fill_high > refine.contact_fill_low:
        # the run's own labels where the contact rule did not run (with the echo rule on it recomputes
        # the echoes: ~100 ms CPU at 114k points, sample_seq1, so only when the fill needs it)
        pre = np.asarray(run_labels_before_contact(seg))
    geo = _labels_without_echoes(seg) if refine.weak_echo_ratio > 0 else pre
    if pre is not None:
        # only the fill labels a point the labels before the rule leave unlabelled (``refine.contact_labels``)
        filled = (pre < 0) & (inst >= 0)
        if filled.any():
            geo = np.where((geo < 0) & filled, inst, geo)
    return np.asarray(geo, np.int32)


def _labels_without_echoes(seg) -> np.ndarray:
    """(N,) the run's labels before the weak-echo and contact rules (``run_geometry``): the pipeline's
    computation of the labels before the contact (``refine.recompute_labels``, as
    ``run_labels_before_contact``) with ``weak_echo_ratio`` 0, whether or not the contact rule ran."""
    from dataclasses import replace

    from clutt3r_core.segmentation.refine import recompute_labels

    return recompute_labels(seg, replace(seg.trace.config.refine, weak_echo_ratio=0.0))


def corrected_geometry_labels(seg, corrected: np.ndarray, n: int, pre: np.ndarray | None = None) -> np.ndarray:
    """(n,) int32: the corrected labels of the run's first n points, with the points the trimming rules
    cleared (the geometry's, ``run_geometry``, unlabelled in the run and left unlabelled by the
    corrections: the contact's lowest millimetres, the weak echoes) given the corrected id of the
    nearest point of their own geometry instance that has one. A merge carries them to the merged
    id, a split to the nearer part; a deleted instance keeps them unlabelled (none of its points has
    an id). Without this a correction brought the contact's labels back into the update's geometry
    (``state._geometry_labels``: the moved clamp read static) and into the grasp target
    (``StepZeroLabels.geometry``). The points the contact fill labelled are the geometry's and take
    their corrected id like any labelled point (a deleted instance's: none).

    Where the nearest point is searched: a fused point (the first ``fused_count(seg)``) among the
    fused points only, as the update's state maps them (it holds no rim voxel), so its first rows
    are the state's labels whatever ``n``; a rim voxel among the first n points (fused or rim,
    the nearer). One search per cleared point: step 0 (``StepZeroLabels.geometry``), the state
    (``state.state_from_segmentation``) and the scenes after updates (``geometry_labels``) read
    this one mapping (session 9: with the rim voxels searched for fused points too, one fused
    point of a split on generated easy seed 11 was I3 at step 0 and I2 in the state).

    ``pre``: ``run_geometry(seg)`` when already computed (the viewer keeps it)."""
    if pre is None:
        pre = run_geometry(seg)
    out = np.array(corrected[:n], np.int32)
    pre = np.asarray(pre)[:n]
    run = np.asarray(seg.instance[:n])
    # a point the run labels that is no geometry stays none, whatever id a correction gave it (none
    # since session 10, when the fill's points joined the geometry: kept for a ``pre`` that lacks them)
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
    """(N,) int32 the geometry (``run_geometry``) of a run's whole cloud (rim voxels included) in
    the ids of a labelling ``instance`` ((N,) int, None: the run's own): the ONE mapping of step 0's
    grasp target (``StepZeroLabels.geometry``), the update state's labels (its fused rows) and the
    scenes after updates (``scene_after.chain_inputs``, the viewer's ``scene_step.chain_inputs_of``).

    The run's own ids: ``run_geometry(seg)`` (``pre``: it, when already computed).
    Corrected ids: ``corrected_geometry_labels`` over the whole cloud (a fused point mapped among the
    fused points, as the state maps it). ``corrected``: whether the labelling is a corrected one (a
    chain: its state's "labels" record has log entries); None: when ``instance`` differs from the
    run's labels."""
    if pre is None:
        pre = run_geometry(seg)
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
