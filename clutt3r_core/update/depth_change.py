"""Change detection and pose from the new depth (ours; ``ChangeConfig.use_depth``).

Runs after the association (associate.py) when the post-interaction view has depth:

1. Every instance with at least ``min_place_points`` visible stored points that the new
   depth can judge is *in place* (static, whatever its projected IoU) or *moved* (its old
   place is seen empty), by ``depth.place_check``. Instances it cannot judge (hidden, out of
   view, segmentation fragments under ``AssociationConfig.min_points``) keep the paper's
   IoU rule and associate.py's rule 5. Instances left unjudged are tested once more with the
   moved ones out of the z-buffer (``recheck_hidden``: what a moved object hid is visible now).
   An in-place one is moved when its unmoved points fail the free-space test on its own mask
   and a registration there passes (``verify_in_place``: a push shorter than the object).
2. Candidate masks: mask candidates no larger than ``max_object_fraction`` of the image whose
   valid-depth pixels are mostly not explained by the in-place instances
   (``depth.explained_pixels``); their points are the unexplained depth pixels (a displaced
   object's mask merged with a static neighbour's keeps only the displaced part).
3. Each moved instance, and each *hidden* one (not judged, but ``unsure``: the paper's rules
   would not call it static), is registered to each candidate of a compatible size
   (``depth.register``); fits that pass ``accept_fitness``, ``accept_consistency`` and
   ``accept_iou`` (``accept_iou_hidden`` for hidden ones; IoU with the candidate's unexplained
   part) are assigned greedily, moved instances first, then best score (fitness x consistency
   x IoU), one mask per instance and one instance per mask, and one object per surface: a fit
   whose moved points lie on an accepted fit's (or, for a hidden instance, on an in-place
   instance's points) is rejected (``max_fit_overlap``). A moved instance with a fit is
   displaced (its pose is the registration's); one without is removed. This searches every
   mask, not only the associated one: on the 12 pairs of seeds 100-103 the displaced object's
   association was wrong or missing in 8 (docs/update.md). Fits are ranked by score x IoU x
   colour agreement (``fit_colour_weight``: two objects of one shape fit one target alike).
4. Moved instances still without a fit are registered to the unexplained depth regions
   (``search_unexplained``, ``_search_regions``), then to pairs of unassigned masks that an
   occluder split (``search_mask_pairs``, ``_search_mask_pairs``), with the same tests.
5. Every fit also needs evidence that the object is there (``depth_evidence.FitEvidence``,
   session 7): a target on the support plane must look like the object, not the table
   (``fit_plane_colour``); a mask owned by an in-place instance, or a region continuing one, must look more like the
   fitted instance than like it (``fit_owner_appearance``). Moved instances still without a fit
   that touch a fitted one share its motion when the free-space test agrees (``carry_contact``:
   segmentation fragments of one object); the others are removed.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from functools import cache

import numpy as np
from scipy.spatial import cKDTree

from clutt3r_core.scene import View
from clutt3r_core.update.associate import Association, project_depth
from clutt3r_core.update.depth import (PlaceCheck, Registration, _consistency, _on_or_in_front, explained_pixels,
                                       mask_points, model_subset, place_check, prepare_model, register, start_rotations,
                                       support_plane, unexplained_regions)
from clutt3r_core.update.depth_evidence import FitEvidence
from clutt3r_core.update.depth_refine import flip_check, refined_registration
from clutt3r_core.update.project import mask_iou, silhouette
from clutt3r_core.update.types import LOSS_NAMES, PoseResult, PoseTrace, UpdateConfig

__all__ = ["Fit", "DepthChanges", "depth_changes", "fit_iou", "registration_result"]


def fit_iou(points: np.ndarray, T: np.ndarray, camera, voxel: float, occluder_depth: np.ndarray | None,
            mask: np.ndarray) -> float:
    """IoU of the points moved by T (z-buffered behind ``occluder_depth``) with ``mask``."""
    p = np.asarray(points, np.float64) @ T[:3, :3].T + T[:3, 3]
    return mask_iou(silhouette(p, camera, voxel, occluder_depth), mask)


@dataclass(frozen=True, eq=False)
class Fit:
    """An accepted registration of a moved instance to a mask candidate (index into the view's
    masks), or, with ``mask_index`` -1, to an unexplained depth region (``region``, (H, W) bool;
    ``ChangeConfig.search_unexplained``)."""

    mask_index: int
    registration: Registration
    iou: float
    region: np.ndarray | None = None
    pair: tuple[int, ...] = ()
    """Indices of the two mask candidates whose union is ``region`` (``ChangeConfig.search_mask_pairs``;
    ``mask_index`` is -1 then): the masks this fit takes, so neither is reported new."""
    carried_by: int = -1
    """The fitted instance whose motion this one shares (``ChangeConfig.carry_contact``: a
    fragment of the same object), its target and registration; -1: fitted itself."""

    def target(self, masks) -> np.ndarray:
        """(H, W) bool: the mask or region the instance was registered to."""
        return self.region if self.mask_index < 0 else masks.masks[self.mask_index]

    def mask_indices(self) -> tuple[int, ...]:
        """The view's mask candidates this fit takes (none for an unexplained region)."""
        return (self.mask_index,) if self.mask_index >= 0 else self.pair


@dataclass(frozen=True, eq=False)
class DepthChanges:
    """What the new depth says (module docstring).

    Attributes:
        place: the in-place test of every instance.
        in_place: ids judged in place (static).
        moved: ids whose old place is seen empty.
        fits: moved (or hidden and unsure) ids with an accepted registration (moved ones
            without one are removed; hidden ones without one are occluded).
        explained: (H, W) bool pixels showing in-place instances.
        registrations: number of registrations run (cost).
        refused: id -> why its last fit that passed the ``accept_*`` tests was refused for lack of evidence that
            the object is there: "plane-colour" (``ChangeConfig.fit_plane_colour``), "owner-appearance" or
            "neighbour-appearance" (``ChangeConfig.fit_owner_appearance``; ``depth_evidence.FitEvidence``).
    """

    place: PlaceCheck
    in_place: frozenset
    moved: frozenset
    fits: dict = field(default_factory=dict)
    explained: np.ndarray | None = None
    registrations: int = 0
    refused: dict = field(default_factory=dict)


def depth_changes(state, view: View, config: UpdateConfig, assoc: Association, status: dict,
                  unsure: set | frozenset = frozenset(), plane=None, embed=None) -> DepthChanges:
    """Judge the instances of ``state`` against ``view.depth`` (module docstring). ``unsure``:
    ids the paper's rules would not call static (unmatched, or IoU < tau_IoU); those whose old
    place the depth cannot judge (hidden) are registered too, on the masks the moved ones left.
    ``plane``: a callable returning the state's support plane (``depth.support_plane`` of its
    background and object points; update.py passes the one it caches for its own tests), None:
    fitted here when the region search needs it. ``embed``: masks (n, H, W) bool -> (n, D)
    unit embeddings of the association's embedder (``ChangeConfig.fit_owner_appearance`` on
    targets without a mask; None: that test is skipped)."""
    cc, ac = config.change, config.association
    cam, depth, voxel = view.camera, view.depth, state.voxel_size
    ids = state.instance_ids
    pc = place_check(state.points, state.instance, ids, cam, depth, voxel, cc.in_place_tol)
    in_place, moved = set(), set()
    big = {int(k) for k in ids if np.count_nonzero(state.instance == k) >= ac.min_points}
    for i, k in enumerate(ids):
        if int(k) not in big or not pc.judged(i, cc.min_place_points):
            continue
        (in_place if pc.fraction(i) >= cc.in_place_fraction else moved).add(int(k))
    if cc.recheck_hidden and moved and big - in_place - moved:
        # pass 2: what the moved instances' old places hid is visible now (ChangeConfig.recheck_hidden)
        keep = np.array([k for k in ids if int(k) not in moved], np.int32)
        p2 = place_check(state.points, state.instance, keep, cam, depth, voxel, cc.in_place_tol)
        rows = {int(k): i for i, k in enumerate(ids)}
        agree, farther, nearer, visible = (np.array(a) for a in (pc.agree, pc.farther, pc.nearer, pc.visible))
        for j, k in enumerate(keep):
            k = int(k)
            if k not in big or k in in_place or not p2.judged(j, cc.min_place_points):
                continue
            (in_place if p2.fraction(j) >= cc.in_place_fraction else moved).add(k)
            i = rows[k]
            agree[i], farther[i], nearer[i], visible[i] = p2.agree[j], p2.farther[j], p2.nearer[j], p2.visible[j]
        pc = PlaceCheck(pc.ids, agree, farther, nearer, visible)
    starts = start_rotations(config.pose.registration_yaw_step_deg)
    if cc.verify_in_place and in_place:
        unplaced = _verify_in_place(state, view, config, assoc, in_place, starts)
        in_place -= unplaced
        moved |= unplaced
    stay = np.array(sorted(in_place), np.int32)
    explained = explained_pixels(state.points, state.instance, stay, cam, depth, voxel, cc.in_place_tol)
    fits: dict = {}
    hidden = {int(k) for k in unsure if int(k) not in in_place | moved and int(k) in big}
    if not moved and not hidden:
        return DepthChanges(pc, frozenset(in_place), frozenset(moved), fits, explained, 0)
    occ = project_depth(state.points, state.instance, stay, cam, voxel) if len(stay) else None
    masks = view.masks
    H, W = masks.shape
    valid = np.isfinite(depth) & (depth > 0)
    cands = []
    for mi in range(len(masks)):
        m = masks.masks[mi]
        mv = m & valid
        n = int(np.count_nonzero(mv))
        if not n or n > ac.max_object_fraction * H * W:
            continue
        rest = m & ~explained  # what is new in the mask (a merged static neighbour removed)
        if np.count_nonzero(rest & valid) < cc.min_rest_fraction * n:
            continue
        if any(mask_iou(rest, c[3]) > 0.9 for c in cands):  # e.g. a parent of one leaf: same remainder
            continue
        pts = mask_points(cam, depth, m, exclude=explained, max_points=250)
        if len(pts) < 30:
            continue
        cands.append((mi, pts, float(np.linalg.norm(np.ptp(pts, axis=0))), rest))
    cand_pts = {c[0]: c[1] for c in cands}
    found, n_reg = _register_all(state, view, config, sorted(moved | hidden), cands, starts, occ,
                                 lambda k: cc.accept_iou if k in moved else cc.accept_iou_hidden, moved)
    refused: dict = {}
    support = cache(lambda: plane() if plane is not None else support_plane(
        state.points[state.instance < 0], state.points[state.instance >= 0], cc.in_place_tol))
    evidence = FitEvidence(state, view, config, assoc, in_place, support, refused, embed)
    taken: list[np.ndarray] = []  # moved points of the accepted fits (ChangeConfig.max_fit_overlap)
    in_place_tree = cKDTree(state.points[np.isin(state.instance, stay)]) if len(stay) else None

    def overlap(q: np.ndarray, pts: list[np.ndarray] | np.ndarray, tree=None) -> float:
        if tree is None:
            if not len(pts):
                return 0.0
            tree = cKDTree(np.concatenate(pts))
        return float(np.mean(tree.query(q, distance_upper_bound=cc.in_place_tol)[0] <= cc.in_place_tol))

    # moved instances first (their old place is seen empty: they are somewhere), then the
    # hidden ones on the masks left (measured on seed 200: one global ranking let a hidden
    # static instance take the displaced object's mask)
    # (a hidden one's fit on an unmoved instance's surface belongs to that object: max_fit_overlap)
    used_m = _take_fits(state, found, lambda f: (f[1] not in moved, -f[0], f[1], f[2]), lambda mi: {mi},
                        lambda mi, reg, iou: Fit(mi, reg, iou), fits, taken, overlap, cc.max_fit_overlap,
                        lambda k, q: (k not in moved and in_place_tree is not None
                                      and overlap(q, [], in_place_tree) > cc.max_fit_overlap),
                        lambda k, ti, reg: evidence(k, reg, cand_pts[ti], ti))
    left = sorted(k for k in moved if k not in fits)
    if cc.search_unexplained and left:
        n_reg += _search_regions(state, view, config, left, moved, fits, taken, occ, starts, overlap, support(),
                                 evidence)
        left = [k for k in left if k not in fits]
    if cc.search_mask_pairs and left:  # last: each pair costs a registration per instance left
        n_reg += _search_mask_pairs(state, view, config, left, [c for c in cands if c[0] not in used_m], fits, taken,
                                    occ, starts, overlap, evidence)
    if cc.carry_contact < 1.0 and left:
        _carry_fragments(state, view, config, [k for k in left if k not in fits], fits)
    for k in fits:  # refused on one target, accepted on another
        refused.pop(k, None)
    return DepthChanges(pc, frozenset(in_place), frozenset(moved), fits, explained, n_reg, refused)


def _verify_in_place(state, view: View, config: UpdateConfig, assoc: Association, in_place: set,
                     starts: np.ndarray) -> set:
    """``ChangeConfig.verify_in_place``: the in-place ids whose unmoved points fail the free-space
    test (``accept_consistency``) while a registration to their own mask's depth points passes
    every ``accept_*`` test (IoU with the mask minus the other in-place instances' pixels)."""
    cc, cam, depth = config.change, view.camera, view.depth
    col = {int(k): i for i, k in enumerate(assoc.instance_ids)}
    out = set()
    for k in sorted(in_place):
        if (mi := int(assoc.mask_index[col[k]]) if k in col else -1) < 0:
            continue
        sel = state.instance == k
        model = state.points[sel].astype(np.float64)
        keep = model_subset(len(model))  # prepare_model's subset, without its normals' cost
        sub = model if keep is None else model[keep]
        if _consistency(sub, np.eye(4), cam, depth, cc.in_place_tol)[0] >= cc.accept_consistency:
            continue  # the unmoved points pass the free-space test
        others = np.array(sorted(in_place - {k}), np.int32)
        expl = explained_pixels(state.points, state.instance, others, cam, depth, state.voxel_size, cc.in_place_tol)
        pts = mask_points(cam, depth, view.masks.masks[mi], exclude=expl, max_points=250)
        if len(pts) < 30:
            continue
        prepared = prepare_model(model, state.colors[sel])
        reg = register(prepared, pts, cam, depth, starts=starts, tol=cc.in_place_tol,
                       keep_consistent=cc.registration_keep_consistent)
        if reg is None or reg.fitness < cc.accept_fitness or reg.consistency < cc.accept_consistency:
            continue
        occ = project_depth(state.points, state.instance, others, cam, state.voxel_size) if len(others) else None
        if fit_iou(model, reg.T_world, cam, state.voxel_size, occ, view.masks.masks[mi] & ~expl) >= cc.accept_iou:
            out.add(k)
    return out


def _carry_fragments(state, view: View, config: UpdateConfig, left: list[int], fits: dict) -> None:
    """``ChangeConfig.carry_contact``: a moved instance no target fitted, at least that fraction
    of whose stored points lie within ``in_place_tol`` of a fitted instance's stored points (a
    segmentation fragment of the same object), moved by that fit's motion: when at least
    ``min_place_points`` of its moved points the camera would see lie on the observed surface,
    and ``accept_consistency`` of those seen (the free-space test), it shares that fit (added to
    ``fits`` with ``carried_by``); otherwise it stays unfitted (removed)."""
    cc = config.change
    trees = {}
    for k in left:
        pk = state.points[state.instance == k].astype(np.float64)
        best = None
        for j, f in list(fits.items()):
            if f.carried_by >= 0:
                continue
            if j not in trees:
                trees[j] = cKDTree(state.points[state.instance == j])
            contact = float(np.mean(trees[j].query(pk, distance_upper_bound=cc.in_place_tol)[0] <= cc.in_place_tol))
            if contact >= cc.carry_contact and (best is None or contact > best[0]):
                best = (contact, j, f)
        if best is None:
            continue
        _, j, f = best
        T = f.registration.T_world
        _, on, front = _on_or_in_front(pk @ T[:3, :3].T + T[:3, 3], view.camera, view.depth, cc.in_place_tol)
        n_on, n = int(on.sum()), int(on.sum() + front.sum())
        if n_on >= cc.min_place_points and n_on >= cc.accept_consistency * n:
            fits[k] = Fit(f.mask_index, f.registration, f.iou, f.region, f.pair, carried_by=j)


def _search_mask_pairs(state, view: View, config: UpdateConfig, left: list[int], cands: list, fits: dict,
                       taken: list[np.ndarray], occ, starts: np.ndarray, overlap, evidence=None) -> int:
    """``ChangeConfig.search_mask_pairs``: register the moved instances that no single mask
    fitted to the union of two unassigned mask candidates (``cands``: (mask index, depth
    points, extent, unexplained pixels)) that something nearer than both separates in the
    image (``_occluded_between``) and that are not one inside the other, with
    ``accept_iou_region`` on the union of their unexplained pixels and one object per surface.
    Accepted fits go into ``fits`` with ``mask_index`` -1, the union as ``region`` and the two
    masks as ``pair``. Returns the registrations run."""
    cc = config.change
    targets, pairs = [], []
    for a in range(len(cands)):
        for b in range(a + 1, len(cands)):
            (ma, pa, _, ra), (mb, pb, _, rb) = cands[a], cands[b]
            both = np.count_nonzero(ra & rb)
            if both > 0.5 * min(np.count_nonzero(ra), np.count_nonzero(rb)):
                continue  # one (mostly) inside the other: their union is one of them
            if not _occluded_between(ra, rb, view.depth, pa, pb, view.camera, cc.in_place_tol):
                continue  # touching masks are most of the time two objects (hard_501, hard_502: 5 pairs, none)
            pts = np.concatenate([pa, pb])
            if len(pts) > 250:  # the registration's cost grows with the points: a single mask's budget
                pts = pts[np.sort(np.random.default_rng(0).choice(len(pts), 250, replace=False))]
            targets.append((len(targets), pts, float(np.linalg.norm(np.ptp(pts, axis=0))), ra | rb))
            pairs.append((ma, mb))
    if not targets:
        return 0
    found, n_reg = _register_all(state, view, config, left, targets, starts, occ, lambda k: cc.accept_iou_region)
    _take_fits(state, found, lambda f: (-f[0], f[1], f[2]), lambda ti: set(pairs[ti]),
               lambda ti, reg, iou: Fit(-1, reg, iou, targets[ti][3], pairs[ti]), fits, taken, overlap,
               cc.max_fit_overlap, evidence=None if evidence is None else lambda k, ti, reg: evidence(
                   k, reg, targets[ti][1], -1, targets[ti][3]))
    return n_reg


def _take_fits(state, found: list, key, takes, make_fit, fits: dict, taken: list[np.ndarray], overlap,
               max_overlap: float, reject=None, evidence=None) -> set:
    """Accept the registrations ``found`` ([(rank, k, target index, registration, IoU)], from
    ``_register_all``) greedily in ``key`` order: one fit per instance, none on a mask or region
    an accepted fit took (``takes(target index)``: the set of ids it takes), none whose moved
    points lie on an accepted fit's (``taken``, ``ChangeConfig.max_fit_overlap``) or that
    ``reject(k, moved points)``, nor one that ``evidence(k, target index, registration)`` (a
    ``depth_evidence.FitEvidence``) refuses. Accepted fits go into ``fits`` (``make_fit(target
    index, registration, IoU)``) and their moved points into ``taken``. Returns the ids taken."""
    used_k, used = set(), set()
    for _, k, ti, reg, iou in sorted(found, key=key):
        t = takes(ti)
        if k in used_k or used & t:
            continue
        T = reg.T_world
        q = state.points[state.instance == k].astype(np.float64) @ T[:3, :3].T + T[:3, 3]
        if overlap(q, taken) > max_overlap or (reject is not None and reject(k, q)):
            continue  # that surface belongs to another object
        if evidence is not None and not evidence(k, ti, reg):
            continue
        used_k.add(k)
        used |= t
        taken.append(q)
        fits[k] = make_fit(ti, reg, iou)
    return used


def _occluded_between(ma: np.ndarray, mb: np.ndarray, depth: np.ndarray, pa: np.ndarray, pb: np.ndarray, camera,
                      tol: float) -> bool:
    """Whether two masks are separated by something in front of both: every valid depth pixel
    on the straight line between their nearest pixels (outside the two masks) is nearer than
    the nearer piece's nearest depth point by more than ``tol`` (an occluder split one object
    in two), and the line crosses at least one such pixel."""
    va, ua = np.nonzero(ma)
    vb, ub = np.nonzero(mb)
    if not len(ua) or not len(ub):
        return False
    tb = cKDTree(np.stack([ub, vb], axis=1))
    dist, j = tb.query(np.stack([ua, va], axis=1))
    i = int(np.argmin(dist))
    p0, p1 = np.array([ua[i], va[i]], float), np.array([ub[j[i]], vb[j[i]]], float)
    n = int(np.ceil(np.linalg.norm(p1 - p0))) + 1
    line = np.round(p0 + np.linspace(0, 1, n)[:, None] * (p1 - p0)).astype(np.int64)
    u, v = line[:, 0], line[:, 1]
    out = ~ma[v, u] & ~mb[v, u]
    d = depth[v[out], u[out]]
    d = d[np.isfinite(d) & (d > 0)]
    if not len(d):
        return False
    z_near = min(float(camera.project(pa)[1].min()), float(camera.project(pb)[1].min()))
    return bool(np.all(d < z_near - tol))


def _search_regions(state, view: View, config: UpdateConfig, left: list[int], moved: set, fits: dict,
                    taken: list[np.ndarray], occ, starts: np.ndarray, overlap, plane: np.ndarray | None,
                    evidence=None) -> int:
    """``ChangeConfig.search_unexplained``: register the moved instances that no mask fitted
    to the regions of new depth that nothing stored explains (``depth.unexplained_regions``:
    not an unmoved instance, not the background, not an accepted fit), with the same
    acceptance tests (``accept_iou_region`` instead of ``accept_iou``) and one object per
    surface; accepted fits go into ``fits`` with ``mask_index`` -1 and their region as
    ``region``. Only the ``region_max_targets`` largest
    regions are searched (each registration costs ~0.1 s CPU). Returns the registrations run."""
    cc = config.change
    cam, depth, voxel = view.camera, view.depth, state.voxel_size
    still = np.array([k for k in state.instance_ids if int(k) not in moved] + [-1], np.int32)
    expl = explained_pixels(state.points, state.instance, still, cam, depth, voxel, cc.in_place_tol)
    for q in taken:  # the accepted fits' moved points (depth_changes appends one per fit)
        expl |= explained_pixels(q, np.zeros(len(q), np.int32), np.zeros(1, np.int32), cam, depth, voxel,
                                 cc.in_place_tol)
    regions = unexplained_regions(cam, depth, expl, plane, cc.region_min_height, cc.region_link,
                                  cc.region_min_pixels)
    targets = []
    for m in regions[: cc.region_max_targets]:
        pts = mask_points(cam, depth, m, erode=1, max_points=250)
        if len(pts) >= 30:
            targets.append((m, pts, float(np.linalg.norm(np.ptp(pts, axis=0)))))
    # a mask split in two by an occluder leaves two regions of one object: their union is a
    # target too, when the two lie within region_pair_gap of each other in 3D
    singles = list(targets)
    trees = [cKDTree(t[1]) for t in singles]
    for a in range(len(singles)):
        for b in range(a + 1, len(singles)):
            (ma, pa, _), (mb, pb, _) = singles[a], singles[b]
            if trees[a].query(pb, distance_upper_bound=cc.region_pair_gap)[0].min() > cc.region_pair_gap:
                continue
            pts = np.concatenate([pa, pb])
            targets.append((ma | mb, pts, float(np.linalg.norm(np.ptp(pts, axis=0)))))
    found, n_reg = _register_all(state, view, config, left,
                                 [(ri, pts, ext, m) for ri, (m, pts, ext) in enumerate(targets)], starts, occ,
                                 lambda k: cc.accept_iou_region, area_bound=True)
    _take_fits(state, found, lambda f: (-f[0], f[1], f[2]), lambda ri: {ri},
               lambda ri, reg, iou: Fit(-1, reg, iou, targets[ri][0]), fits, taken, overlap, cc.max_fit_overlap,
               evidence=None if evidence is None else lambda k, ri, reg: evidence(k, reg, targets[ri][1], -1,
                                                                                  targets[ri][0]))
    return n_reg


def _register_all(state, view: View, config: UpdateConfig, ks: list[int], targets: list, starts: np.ndarray, occ,
                  accept_iou, moved=None, area_bound: bool = False) -> tuple[list, int]:
    """Register each instance of ``ks`` to each target (index, (n, 3) depth points, their
    extent, (H, W) bool pixels the fit's IoU is measured on) whose extent its size allows, and
    keep the registrations that pass ``accept_fitness`` / ``accept_consistency`` and reach
    ``accept_iou(k)``: the registration's pick, or for the ids in ``moved`` (None: all of
    ``ks``) the first of its ``registration_alternatives`` next-best poses that passes.
    ``area_bound``: also skip targets too large for the object to reach that
    IoU (unexplained regions). Returns ([(score x IoU, k, target index, registration, IoU)],
    registrations run)."""
    cc, cam = config.change, view.camera
    found, n_reg = [], 0

    def passes(r: Registration, model: np.ndarray, target: np.ndarray, min_iou: float) -> float | None:
        # every accept_* test (pick, alternative, refinement, half turn): the IoU when it passes, else None
        if r.fitness < cc.accept_fitness or r.consistency < cc.accept_consistency:
            return None
        iou = fit_iou(model, r.T_world, cam, state.voxel_size, occ, target)
        return iou if iou >= min_iou else None
    for k in ks:
        sel = state.instance == k
        model, colors = state.points[sel].astype(np.float64), state.colors[sel]
        diam = float(np.linalg.norm(np.ptp(model, axis=0)))
        prepared = None  # register's per-instance work, once for all this instance's targets
        for ti, pts, ext, target in targets:
            if ext > cc.max_extent_ratio * diam + 0.01:
                continue
            if area_bound:
                # IoU >= accept_iou needs the region within 1 / accept_iou of the largest area the
                # object can cover: a disc of its diameter (isodiametric) at its nearest possible depth
                z = max(float(np.min(cam.project(pts)[1])) - diam, 0.05)
                if cc.accept_iou * np.count_nonzero(target) > np.pi / 4 * (cam.fx * diam / z) * (cam.fy * diam / z):
                    continue
            if prepared is None:
                prepared = prepare_model(model, colors)
            # next-best poses for moved instances only (their old place is seen empty: they are
            # somewhere): a hidden one's is a static object's chance to be flagged (hard_902: an
            # alternative passed accept_iou_hidden on another object's mask, IoU 0.54)
            alt = cc.registration_alternatives if moved is None or k in moved else 0
            reg = register(prepared, pts, cam, view.depth, starts=starts, tol=cc.in_place_tol,
                           rgb=view.rgb, photo_weight=config.pose.registration_photo_weight,
                           tie_margin=config.pose.registration_tie_margin, keep_consistent=cc.registration_keep_consistent,
                           alternatives=alt)
            n_reg += 1
            if reg is None:
                continue
            # the registration's pick first, then its next-best poses: the first that passes every
            # acceptance test (ChangeConfig.registration_alternatives; the pick's result is unchanged
            # when it passes)
            for reg in (reg,) + reg.alternatives:
                if (iou := passes(reg, model, target, accept_iou(k))) is not None:
                    break
            else:
                continue
            if config.pose.registration_refine_iterations:
                # the one-way ICP's partial-view bias (depth_refine.py); the refined pose replaces
                # the ICP's only when it passes the same tests
                ref = refined_registration(reg, prepared, pts, cam, view.depth, cc.in_place_tol,
                                           iterations=config.pose.registration_refine_iterations,
                                           radius_start=config.pose.registration_refine_radius[0],
                                           radius_end=config.pose.registration_refine_radius[1],
                                           rgb=view.rgb, keep=config.pose.registration_refine_keep)
                if ref is not reg and (iou_ref := passes(ref, model, target, accept_iou(k))) is not None:
                    reg, iou = ref, iou_ref
            if config.pose.registration_flip_check and view.rgb is not None:
                flip, flipped = flip_check(reg, prepared, pts, cam, view.depth, view.rgb, cc.in_place_tol,
                                           score_margin=config.pose.registration_flip_margins[0],
                                           photo_margin=config.pose.registration_flip_margins[1],
                                           iterations=config.pose.registration_refine_iterations,
                                           radius_start=config.pose.registration_refine_radius[0],
                                           radius_end=config.pose.registration_refine_radius[1],
                                           symmetric=config.pose.registration_flip_symmetric)
                if flipped and (iou_flip := passes(flip, model, target, accept_iou(k))) is not None:
                    reg, iou = flip, iou_flip
            rank = reg.score * iou
            if cc.fit_colour_weight and view.rgb is not None:
                # two objects of one shape fit one target alike (easy_501: a baseball and an
                # orange, 0.77 vs 0.76): their colours on the observed surface tell them apart
                photo = _consistency(model, reg.T_world, cam, view.depth, cc.in_place_tol, colors, view.rgb)[1]
                if np.isfinite(photo):
                    rank *= max(0.0, 1.0 - cc.fit_colour_weight * photo)
            found.append((rank, k, ti, reg, iou))
    return found, n_reg


def registration_result(reg: Registration, points: np.ndarray, camera, voxel: float,
                        occluder_depth: np.ndarray | None, mask: np.ndarray, iou_before: float) -> PoseResult:
    """The registration as a ``PoseResult`` (the replay and the saved traces show its ICP
    iterations): one stage, losses ``total`` = ``depth`` = the iteration's truncated mean
    scene-to-model distance in cm (chamfer, photo and reg_z are not computed: 0), IoU with
    the mask after each iteration."""
    t0 = time.perf_counter()
    path = reg.path if reg.path is not None else reg.T_world[None]
    cost = reg.path_cost if reg.path_cost is not None else np.array([reg.rmse])
    losses = np.zeros((len(path), len(LOSS_NAMES)))
    losses[:, 0] = losses[:, LOSS_NAMES.index("depth")] = 100.0 * cost
    iou = np.array([fit_iou(points, T, camera, voxel, occluder_depth, mask) for T in path])
    trace = PoseTrace(np.zeros(len(path), np.int8), path, losses, iou)
    return PoseResult(reg.T_world, iou_before, float(iou[-1]), trace, 1, time.perf_counter() - t0)
