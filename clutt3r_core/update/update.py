"""One scene update: association, change detection, pose update (Sec. III-C).

``update_scene(state, view)`` -> ``UpdateResult``; ``apply_update`` (state.py) turns it into
the next state.

Change detection (Sec. III-C.3): every matched instance's stored points are z-buffered into
the new camera together with the other present instances (removed ones are gone, so what
they hid counts as visible); its IoU with its new mask below tau_IoU flags it displaced.
A second pass (ours) re-checks each flagged instance without the other flagged instances in
the z-buffer and ignoring the pixels where those were (old projection) or are (new mask):
a static object that a displaced neighbour used to hide, or now hides, must not be flagged
for its neighbour's motion. Static instances are left untouched.

With new depth (ours, ``ChangeConfig.use_depth``, depth_change.py): instances whose stored
points agree with the new depth are static whatever their IoU; those whose old place is seen
empty (and hidden IoU-flagged ones) are registered against the mask candidates: displaced with
the registration's pose when a fit passes, else removed (hidden ones: occluded). The paper's
silhouette/photometric fit then runs only for views without depth (or, optionally, after the
registration: ``PoseConfig.refine_registration``).

Without depth (ours, ``ChangeConfig.use_photo``, photo_change.py): the stored points' colours
are compared with the new image first; instances found in place are static whatever their
projected IoU (and stay out of the semantic stage of the association), unmatched ones found
in place are static and unmatched ones found gone are removed (associate.py rule 5); the
others keep the paper's IoU test and silhouette/photometric fit. Instances too small for the
test are fragments, kept (``photo_fragment_points``), and an instance reported removed that a
displaced one now stands in front of is occluded (``hidden_by_moved_fraction``).
"""

from __future__ import annotations

import time
from dataclasses import replace
from functools import cache

import numpy as np

from clutt3r_core.errors import SceneError
from clutt3r_core.scene import MaskCandidates, View
from clutt3r_core.segmentation.trees import build_instance_tree
from clutt3r_core.update.associate import (Association, Projection, associate, project_depth, project_instances,
                                           unmatched_status)
from clutt3r_core.update.depth import support_plane
from clutt3r_core.update.depth_change import depth_changes, fit_iou, registration_result
from clutt3r_core.update.newobj import new_object_candidates, next_instance_id
from clutt3r_core.update.photo_change import PhotoCheck, photo_at_pose, photo_check
from clutt3r_core.update.project import mask_iou
from clutt3r_core.update.state import SceneState, moved_points
from clutt3r_core.update.types import (TAU_SEM_BY_EMBEDDER, InstanceUpdate, NewInstance, NewMask, PoseProblem,
                                       UpdateConfig, UpdateResult)

__all__ = ["update_scene", "UpdateDetails"]


class UpdateDetails:
    """Intermediates of the last ``update_scene`` call, for the viewer and the tests
    (the association with its similarities, the projection before the update)."""

    association: Association
    projection: Projection
    depth: object = None
    """``depth_change.DepthChanges`` when the view had depth and ``ChangeConfig.use_depth``."""
    photo: PhotoCheck | None = None
    """The photometric in-place test when it ran (no depth cues, ``ChangeConfig.use_photo``)."""
    photo_verdict: dict | None = None
    """instance id -> "in-place" / "present" (between) / "gone" for the judged instances,
    "fragment" for unjudged ones under ``ChangeConfig.photo_fragment_points``, "hidden" / "agree"
    for other unjudged ones (``ChangeConfig.photo_unjudged_rules``)."""


def _moved(res, centroid: np.ndarray, iou_before: float, config: UpdateConfig) -> bool:
    """ChangeConfig.verify: the optimised motion is real (better fit and a real move)."""
    c = config.change
    T = res.T_world
    shift = float(np.linalg.norm(T[:3, :3] @ centroid + T[:3, 3] - centroid))
    angle = float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1))))
    return res.iou_after >= iou_before + c.min_iou_gain and (shift >= c.min_translation or angle >= c.min_rotation_deg)


def _iou_without(a: np.ndarray, b: np.ndarray, ignore: np.ndarray) -> float:
    keep = ~ignore
    return mask_iou(a & keep, b & keep)


def _hidden_by_moved(records: list[InstanceUpdate], state: SceneState, proj_all: Projection, cam, voxel: float,
                     scale: float, fraction: float, margin: float) -> list[InstanceUpdate]:
    """Views without depth (``ChangeConfig.hidden_by_moved_fraction``): an instance reported
    removed whose visible projection is now mostly covered by a displaced instance at its new
    pose, nearer to the camera by ``margin`` or more, is hidden there, not known to be gone:
    occluded ("hidden-by-moved"). The photometric test and rule 5 compare its old place with
    the image before any pose is known, so they see the moved object's colours there."""
    moved = {r.instance: r.T_world for r in records if r.status == "displaced" and r.T_world is not None}
    gone = [r for r in records if r.status == "removed"]
    if not moved or not gone:
        return records
    after = project_depth(moved_points(state, moved).astype(np.float32), state.instance,
                          np.array(sorted(moved), np.int32), cam, voxel, scale)
    out = []
    for r in records:
        if r.status == "removed":
            vis = proj_all.label == r.instance
            n = int(np.count_nonzero(vis))
            if n and np.count_nonzero(after[vis] < proj_all.depth[vis] - margin) >= fraction * n:
                r = replace(r, status="occluded", match=(r.match + "+" if r.match else "") + "hidden-by-moved")
        out.append(r)
    return out


class _LazyOptimizer:
    """The registry's ``config.optimizer``, built at its first ``optimize``: an update that fits
    no silhouette (with depth the registration moves the instances; an unchanged scene) does
    not import torch (1.2 s CPU, measured on this machine; docs/update.md, speed)."""

    def __init__(self, config: UpdateConfig) -> None:
        self._config, self._opt = config, None

    def optimize(self, problem):
        if self._opt is None:
            from clutt3r_core.registry import create_backend

            self._opt = create_backend("pose_optimizer", self._config.optimizer, config=self._config.pose)
        return self._opt.optimize(problem)


def update_scene(
    state: SceneState,
    view: View,
    config: UpdateConfig = UpdateConfig(),
    *,
    optimizer=None,
    embedder=None,
    details: UpdateDetails | None = None,
) -> UpdateResult:
    """Update ``state`` from one post-interaction ``view`` (RGB, its masks, depth optional).

    optimizer: a ``PoseOptimizer`` (default: the registry's ``config.optimizer`` built with
    ``config.pose``); embedder: a ``MaskEmbedder`` (default: ``state.embedder``).

    numpy's BLAS runs on one thread for the call (threadpoolctl; restored after), as in
    ``pipeline.segment``: the products here are (N, 3) x (3, 3) projections of the whole scene,
    where OpenBLAS's second thread only spins (ours: 48 vs 4 ms of CPU for 110 k points on the
    loaded 2-core machine; the row split gives the same values, docs/update.md session 6).
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1, user_api="blas"):
        return _update_scene(state, view, config, optimizer=optimizer, embedder=embedder, details=details)


def _update_scene(state: SceneState, view: View, config: UpdateConfig, *, optimizer, embedder,
                  details: UpdateDetails | None) -> UpdateResult:
    t0 = time.perf_counter()
    if view.masks is None:
        raise SceneError(f"{view.name or f'frame {view.frame}'}: the post-interaction view has no mask candidates")
    if optimizer is None:
        optimizer = _LazyOptimizer(config)
    if embedder is None:
        from clutt3r_core.embeddings import create_embedder

        embedder = create_embedder(state.embedder)
    if config.association.tau_sem is None:  # the embedder's own threshold (types.TAU_SEM_BY_EMBEDDER)
        config = replace(config, association=replace(
            config.association, tau_sem=TAU_SEM_BY_EMBEDDER.get(state.embedder, 0.65)))
    cam = view.camera
    masks: MaskCandidates = view.masks
    ids = state.instance_ids
    voxel, scale = state.voxel_size, config.change.splat_scale

    tree = build_instance_tree(masks, view.frame)
    def mask_emb(idx: np.ndarray) -> np.ndarray:  # lazily: only masks that reach the semantic stage
        return embedder.embed_masks(view.rgb, masks.masks[idx])

    proj_all = project_instances(state.points, state.instance, ids, cam, voxel, scale, colors=state.colors)
    cc = config.change
    # the support plane (depth.support_plane), fitted at its first use: the region search, the
    # presence test of each unfitted moved instance and the new objects use the same one (~30 ms
    # of RANSAC a fit)
    plane = cache(lambda: support_plane(state.points[state.instance < 0], state.points[state.instance >= 0],
                                        cc.in_place_tol))
    photo: dict[int, str] = {}
    pc = None
    if cc.use_photo and not (cc.use_depth and view.depth is not None):
        pc = photo_check(state.points, state.colors, state.instance, ids, cam, view.rgb, voxel,
                         tol_min=cc.photo_tol_min, tol_sigma=cc.photo_tol_sigma, search_px=cc.photo_search_px,
                         context_radius=cc.photo_context_radius, context_share=cc.photo_context_share)
        for i, k in enumerate(ids):
            k = int(k)
            if pc.judged(k, cc.photo_min_points, cc.photo_min_informative):
                f = pc.fraction(k)
                photo[k] = ("in-place" if f >= cc.photo_in_place_fraction
                            else "gone" if f <= cc.photo_gone_fraction else "present")
            elif proj_all.n_points[i] < cc.photo_fragment_points:
                photo[k] = "fragment"  # ChangeConfig.photo_fragment_points
            elif cc.photo_unjudged_rules and pc.visible[pc.index(k)] < cc.photo_min_points:
                photo[k] = "hidden"  # the stored scene, background included, hides it from this camera
            elif cc.photo_unjudged_rules and pc.informative[pc.index(k)] >= cc.photo_min_points and (
                    pc.fraction(k) >= cc.photo_in_place_fraction):
                photo[k] = "agree"  # enough informative points agree; too few of its visible ones are informative
        if details is not None:
            details.photo, details.photo_verdict = pc, photo
    assoc = associate(view, proj_all, state.embeddings, mask_emb, config.association, tree=tree, photo=photo)
    if details is not None:
        details.association, details.projection = assoc, proj_all

    status = {int(k): s for k, s in zip(ids, assoc.unmatched_status) if s}
    new_mask = {int(k): masks.masks[mi] for k, mi in zip(ids, assoc.mask_index) if mi >= 0}
    present = np.array([k for k in ids if status.get(int(k)) != "removed"], np.int32)
    # pass 1: z-buffer of every instance still there
    proj = project_instances(state.points, state.instance, present, cam, voxel, scale)
    iou = {k: mask_iou(proj.label == k, m) for k, m in new_mask.items()}
    flagged = {k for k, v in iou.items() if v < config.change.tau_iou}
    # pass 2: re-check flagged instances without the other flagged ones (module docstring)
    if len(flagged) > 1 or (flagged and len(new_mask) > 1):
        for k in sorted(flagged):
            others = flagged - {k}
            if not others:
                continue
            keep = np.array([j for j in present if j not in others], np.int32)
            pk = project_instances(state.points, state.instance, keep, cam, voxel, scale)
            ignore = np.zeros(masks.shape, bool)
            for j in others:
                ignore |= (proj.label == j) | new_mask[j]
            v2 = _iou_without(pk.label == k, new_mask[k], ignore)
            if v2 >= config.change.tau_iou:
                iou[k] = v2
    # photometrically in place: static whatever the IoU (ours, photo_change.py)
    displaced = sorted(k for k, v in iou.items() if v < config.change.tau_iou and photo.get(k) != "in-place")

    # with depth (ours, depth_change.py): in place -> static; seen gone -> registered or removed
    dc = None
    if config.change.use_depth and view.depth is not None:
        unsure = {int(k) for k in ids if int(k) not in iou or iou[int(k)] < config.change.tau_iou}
        dc = depth_changes(state, view, config, assoc, status, unsure, plane,
                           embed=lambda m: embedder.embed_masks(view.rgb, m))
        if details is not None:
            details.depth = dc
        hidden_flagged = set(displaced) - dc.in_place - dc.moved - set(dc.fits)
        displaced = sorted(set(dc.fits))

    records: list[InstanceUpdate] = []
    static_ids = np.array([k for k in present if int(k) not in displaced and (dc is None or int(k) not in dc.moved)],
                          np.int32)
    occ_depth = project_depth(state.points, state.instance, static_ids, cam, voxel, scale) if displaced else None
    for i, k in enumerate(ids):
        k = int(k)
        mi = int(assoc.mask_index[i])
        mid = int(masks.ids[mi]) if mi >= 0 else -1
        if dc is not None and (k in dc.moved or k in dc.fits):
            fit = dc.fits.get(k)
            if fit is None:  # its old place is seen empty and no mask or region fits it: grasped ...
                new_mask.pop(k, None)
                if cc.unfitted_presence and unmatched_status(
                        view, proj_all, i, config.association,
                        plane=plane() if cc.presence_above_support else None)[0] == "static":
                    # ... unless its projection's pixels still show it (rule 5's depth presence
                    # test; ChangeConfig.unfitted_presence): the per-point place test was ambiguous
                    records.append(InstanceUpdate(k, "static", iou.get(k), iou.get(k), None, mid,
                                                  "present-depth"))
                    continue
                # (the association's rule 5 may have said "present-depth" without the support plane)
                how = assoc.match[i] if assoc.match[i] not in ("", "present-depth") else "depth"
                records.append(InstanceUpdate(k, "removed", None, None, None, -1, how))
                continue
            sel = state.instance == k
            m_k = fit.target(masks)
            fit_mid = int(masks.ids[fit.mask_index]) if fit.mask_index >= 0 else -1
            fit_how = ("depth-carried" if fit.carried_by >= 0 else "depth-registration" if fit.mask_index >= 0
                       else "depth-region")
            ib = mask_iou(proj.label == k, m_k)  # the paper's IoU before, for the record
            T, res = fit.registration.T_world, registration_result(fit.registration, state.points[sel], cam, voxel,
                                                                   occ_depth, m_k, ib)
            if config.pose.refine_registration:
                res = optimizer.optimize(PoseProblem(
                    instance=k, points=state.points[sel], colors=state.colors[sel], camera=cam, rgb=view.rgb,
                    mask=m_k, occluder_depth=occ_depth, depth=view.depth, voxel_size=voxel, T_init=T))
                T = res.T_world
            if k not in dc.moved and config.change.verify and not _moved(
                    replace(res, T_world=T), state.points[sel].astype(np.float64).mean(axis=0), -1.0, config):
                # hidden at its old place, found (nearly) there in the new view: it did not move
                records.append(InstanceUpdate(k, "static", ib, ib, None, fit_mid, fit_how, pose=res))
                continue
            ia = fit_iou(state.points[sel], T, cam, voxel, occ_depth, m_k)
            new_mask[k] = m_k
            records.append(InstanceUpdate(k, "displaced", ib, ia, T, fit_mid, fit_how, pose=res))
            continue
        if dc is not None and k in dc.in_place:
            v = iou.get(k)
            records.append(InstanceUpdate(k, "static", v, v, None, mid, assoc.match[i] or "present-depth"))
            continue
        if dc is not None and k in hidden_flagged:
            # matched, IoU < tau_IoU, but the depth sees neither its old place nor a new one that
            # fits: hidden (or a fragment under min_points), kept unchanged without a silhouette fit
            # (ours: measured on seeds 200-201, these fits were most of the time and flagged statics)
            new_mask.pop(k, None)
            records.append(InstanceUpdate(k, "occluded", iou[k], None, None, mid, "depth-hidden"))
            continue
        if k in status:  # unmatched: removed, occluded, or present without a mask of its own (static)
            records.append(InstanceUpdate(k, status[k], None, None, None, mid, assoc.match[i]))
        elif k not in displaced:
            how = assoc.match[i] + ("+photo" if photo.get(k) == "in-place" and iou[k] < cc.tau_iou else "")
            records.append(InstanceUpdate(k, "static", iou[k], iou[k], None, mid, how))
        else:
            sel = state.instance == k
            pb = PoseProblem(
                instance=k, points=state.points[sel], colors=state.colors[sel], camera=cam, rgb=view.rgb,
                mask=new_mask[k], occluder_depth=occ_depth, depth=view.depth, voxel_size=voxel,
            )
            res = optimizer.optimize(pb)
            worse = False
            if pc is not None and cc.verify and cc.photo_verify_fit:
                # the colours must support the move at least as much as staying (ours)
                n1, f1 = photo_at_pose(pb.points, pb.colors, res.T_world, cam, view.rgb, voxel, occ_depth,
                                       pc.gain, pc.tol, cc.photo_search_px)
                n0, f0 = photo_at_pose(pb.points, pb.colors, np.eye(4), cam, view.rgb, voxel, occ_depth,
                                       pc.gain, pc.tol, cc.photo_search_px)
                worse = min(n0, n1) >= cc.photo_min_points and f1 < f0
            if config.change.verify and "semantic" in assoc.match[i] and (
                    res.iou_after < config.change.min_fit_iou or worse):
                # an appearance match that no rigid motion fits is not this object: unmatched
                st_k, how_k = unmatched_status(view, proj_all, i, config.association, photo.get(k, ""))
                records.append(InstanceUpdate(k, st_k, None, None, None, -1, how_k or "semantic-rejected", pose=res))
            elif config.change.verify and (worse or not _moved(res, state.points[sel].mean(axis=0), iou[k], config)):
                records.append(InstanceUpdate(k, "static", iou[k], iou[k], None, mid, assoc.match[i], pose=res))
            else:
                records.append(InstanceUpdate(k, "displaced", iou[k], res.iou_after, res.T_world, mid,
                                              assoc.match[i], pose=res))
    if dc is None and cc.hidden_by_moved_fraction < 1.0:
        records = _hidden_by_moved(records, state, proj_all, cam, voxel, scale, cc.hidden_by_moved_fraction,
                                   config.association.nearer_margin)
    taken = set() if dc is None else {mi for f in dc.fits.values() for mi in f.mask_indices()}
    # a mask the association gave to an instance finally reported removed is unmatched after all
    gone = {int(r.instance) for r in records if r.status == "removed"}
    freed = [int(mi) for k, mi in zip(ids, assoc.mask_index) if mi >= 0 and int(k) in gone]
    new_idx = sorted({mi for mi in list(assoc.new_masks) + freed if mi not in taken})
    added, became = _add_new(state, view, config, records, new_idx, mask_emb, plane) if dc is not None else ([], {})
    new = tuple(NewMask(int(masks.ids[mi]), int(np.count_nonzero(masks.masks[mi])), became.get(mi, -1))
                for mi in new_idx)
    change = np.zeros((len(ids) + len(added), *masks.shape), bool)
    for i, k in enumerate(ids):
        if int(k) in new_mask:
            change[i] = new_mask[int(k)]
    for j, (rec, a, mi) in enumerate(added):
        records.append(rec)
        change[len(ids) + j] = masks.masks[mi]
    return UpdateResult(frame=view.frame, instances=tuple(records), new_masks=new, change_masks=change,
                        projected=proj_all.label, time_s=time.perf_counter() - t0, added=tuple(a for _, a, _ in added),
                        camera=view.camera)


def _add_new(state: SceneState, view: View, config: UpdateConfig, records: list[InstanceUpdate], new_idx: list[int],
             mask_emb, plane) -> tuple[list, dict]:
    """Views with depth (``ChangeConfig.new_objects``, newobj.py): the new masks that show an
    object the updated state does not hold become instances with fresh ids. ``plane``: () -> the
    support plane (``depth.support_plane``), called only when a new mask is examined. Returns
    ([(record, NewInstance, mask index)], mask index -> instance id)."""
    if not config.change.new_objects or not new_idx:
        return [], {}
    motions = {r.instance: r.T_world for r in records if r.status == "displaced"}
    removed = {r.instance for r in records if r.status == "removed"}
    cands = new_object_candidates(state, view, new_idx, motions, removed, config, plane())
    masks, cam, out, became = view.masks, view.camera, [], {}
    nid = next_instance_id(state)
    for c in cands:
        emb = None
        if state.embeddings.shape[1] > 0:
            # the stored instances' embeddings are their masks' (Sec. III-C.1); a new one has one mask
            e = np.asarray(mask_emb(np.array([c.mask_index]))[0], np.float32)
            emb = e / max(float(np.linalg.norm(e)), 1e-12)
        m = masks.masks[c.mask_index]
        ia = fit_iou(c.points, np.eye(4), cam, state.voxel_size, None, m)
        rec = InstanceUpdate(nid, "new", None, ia, None, int(masks.ids[c.mask_index]), "new-depth")
        out.append((rec, NewInstance(nid, int(masks.ids[c.mask_index]), c.points, c.colors, emb), c.mask_index))
        became[c.mask_index] = nid
        nid += 1
    return out, became
