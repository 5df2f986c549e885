"""Scene-update benchmark on generated pre/post pairs (issue 10 acceptance, Sec. III-C).

For each pair (``clutt3r synth --prepost``: one object removed, a neighbour pushed 5-9 cm and
turned 20-60 deg, one post view with depth and Grounded-SAM-like masks): segment the initial
views, run ``update_scene`` on the post view, and score against ``gt/interaction.json``:

- instances are mapped to ground-truth objects by their points (nearest labelled GT point
  within 1 cm, majority; the instance with most points of an object is its *main* instance);
- removed: recall = the removed object's main instance is reported removed (over all pairs,
  and over the pairs where the initial segmentation made an instance of it at all); precision
  = of the instances reported removed, the fraction that belong to the removed object;
- displaced: the same with the displaced object (recall counted over pairs where the object is
  visible in the post view, >= 200 px of the GT map);
- static flagged: instances of untouched objects reported displaced or removed;
- pose error of the displaced object's main instance: rotation angle of R_est R_gt^T (deg) and
  distance between the instance centroid moved by the estimate and by the truth (cm); the
  rotation error up to the object's symmetries (``sym_rot_err_deg``: symmetries found on the
  GT surface points, ``symmetries`` / ``symmetry_axes``; a ball counts 0, a can only its axis
  direction); and the symmetry-aware ADD-S (mean distance of each estimated point to the
  nearest true point, cm), because a can or a ball turned about its axis looks the same from
  every yaw;
- IoU before/after of that instance, and wall and CPU time per update (the whole ``update_scene``;
  CPU time is the fair number on a shared machine: torch runs on one thread);
- new objects (views with depth, ``newobj.py``; ``new_object_scores``): each added instance is
  labelled with the GT object under the majority of its points' pixels in the post view (-1 =
  table / background: noise); the GT objects with no instance before the update and >= 200 px
  in the post view (not the removed one) are *new*; one is found when an added instance has
  3D IoU >= 0.5 with it (1 cm voxels; the reference is the object's post-view pixels
  back-projected with the post depth: one view shows only the object's front, which is all an
  added instance can hold). An added instance is *right* when its object is new or is the
  displaced object whose instance the update reported removed (re-added: it has an instance
  again), a *duplicate* when its object still has an instance, *noise* when it has no object.

Usage::

    .venv/bin/python benchmarks/bench_update.py --out /tmp/bench_update [--pairs 12] [--seed0 100] \
        [--embedder run] [--no-depth] [--no-depth-cues] [--refine-registration] [--no-photo] [--tilt-starts] \
        [--no-region-search] [--no-unfitted-presence] [--registration-before]

Scenes and runs are cached under ``--out`` (delete to regenerate). Prints a markdown table and
writes ``results.json`` and one overlay PNG per pair.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from clutt3r_core.io import load_scene
from clutt3r_core.io.images import write_png
from clutt3r_core.runs import save_run
from clutt3r_core.scene import View
from clutt3r_core.update.overlay import update_overlay
from clutt3r_core.update.embed import resolve_embedder, with_embedder
from clutt3r_core.update.state import state_from_run
from clutt3r_core.update.types import ChangeConfig, PoseConfig, UpdateConfig
from clutt3r_core.update.update import update_scene

PRESETS = ("easy", "intermediate", "hard")


def make_pair(root: Path, preset: str, seed: int) -> tuple[Path, Path]:
    from clutt3r_core.pipeline import segment
    from clutt3r_core.synth import SynthConfig, generate, write_synth_scene

    scene_dir, run_dir = root / f"{preset}_{seed}" / "scene", root / f"{preset}_{seed}" / "run"
    if not (scene_dir / "gt" / "interaction.json").is_file():
        res = generate(SynthConfig(seed=seed, preset=preset, prepost=True), progress=False)
        write_synth_scene(res.scene, scene_dir, info=res.info)
    if not (run_dir / "instances.npz").is_file():
        sc = load_scene(scene_dir)
        save_run(segment(sc), run_dir, scene_root=scene_dir)
    return scene_dir, run_dir


def gt_mapping(state, scene) -> tuple[dict[int, int], dict[int, int]]:
    """(instance -> GT object or -1, GT object -> main instance)."""
    gt = scene.ground_truth
    tree = cKDTree(gt.points)
    d, j = tree.query(state.points, distance_upper_bound=0.01)
    lab = np.where(np.isfinite(d), gt.point_labels[np.minimum(j, len(gt.points) - 1)], -1)
    inst_obj, counts = {}, {}
    for k in state.instance_ids:
        lk = lab[state.instance == k]
        lk = lk[lk >= 0]
        if not len(lk):
            inst_obj[int(k)] = -1
            continue
        o = int(np.bincount(lk).argmax())
        inst_obj[int(k)] = o if np.mean(lk == o) >= 0.5 else -1
        counts.setdefault(o, []).append((int(np.sum(lk == o)), int(k)))
    main = {o: max(v)[1] for o, v in counts.items()}
    return inst_obj, main


def rot_err_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra @ Rb.T) - 1) / 2, -1, 1))))


SYM_STEP_DEG = 10
SYM_TOL = 1.25
"""A rotation S about a principal axis through the centroid (10 deg grid) is a symmetry of the
object's ground-truth surface points when one random half of them, turned by S, lies as close
to the other half as the unturned half does (mean nearest-neighbour distance <= 1.25 x, i.e.
within the sampling noise; measured on seed 200: spheres, cans and boxes' 180 deg turns pass,
other turns give 2-10 x)."""


def _symmetry_probe(points: np.ndarray, seed: int) -> tuple[cKDTree, np.ndarray, float, np.ndarray]:
    """Two disjoint random halves of the centred surface (a k-d tree of one, the other as
    probes), the probes' mean nearest distance (the surface's own sampling floor) and the
    principal axes (columns of V): what both symmetry tests start from."""
    rng = np.random.default_rng(seed)
    idx = rng.permutation(len(points))
    h = min(len(points) // 2, 1500)
    c = points.mean(axis=0)
    A, B = points[idx[:h]] - c, points[idx[h : 2 * h]] - c
    tree = cKDTree(A)
    floor = float(tree.query(B)[0].mean())
    _, V = np.linalg.eigh(np.cov((points - c).T))
    return tree, B, floor, V


def symmetry_axes(points: np.ndarray, seed: int = 0) -> list[np.ndarray]:
    """Unit principal axes about which EVERY turn of the 10 deg grid is a symmetry (continuous
    symmetry: a can, a bowl; two or more such axes: a ball)."""
    from scipy.spatial.transform import Rotation

    tree, B, floor, V = _symmetry_probe(points, seed)
    out = []
    for ax in V.T:
        if all(tree.query(B @ Rotation.from_rotvec(ax * np.deg2rad(a)).as_matrix().T)[0].mean() <= SYM_TOL * floor
               for a in range(SYM_STEP_DEG, 360, SYM_STEP_DEG)):
            out.append(ax)
    return out


def symmetries(points: np.ndarray, seed: int = 0) -> list[np.ndarray]:
    """Rotation matrices (about the centroid) that map the object's surface onto itself."""
    from scipy.spatial.transform import Rotation

    tree, B, floor, V = _symmetry_probe(points, seed)
    out = [np.eye(3)]
    for ax in V.T:
        for ang in range(SYM_STEP_DEG, 360, SYM_STEP_DEG):
            S = Rotation.from_rotvec(ax * np.deg2rad(ang)).as_matrix()
            if tree.query(B @ S.T)[0].mean() <= SYM_TOL * floor:
                out.append(S)
    return out


def _closure(syms: list[np.ndarray], limit: int = 72) -> list[np.ndarray]:
    """The group the found symmetries generate (products), up to ``limit`` elements."""
    out = [np.eye(3)]
    frontier = list(syms)
    while frontier and len(out) < limit:
        S = frontier.pop()
        if any(np.allclose(S, G, atol=1e-6) for G in out):
            continue
        out.append(S)
        frontier += [S @ G for G in syms]
    return out


def sym_rot_err_deg(R_est: np.ndarray, R_gt: np.ndarray, syms: list[np.ndarray],
                    axes: list[np.ndarray] | None = None) -> float:
    """Rotation error up to the object's symmetries (S acts first, in the pre-interaction
    world frame about the centroid):

    - two or more continuous axes (a ball): 0, no rotation is observable;
    - one continuous axis a (a can): the angle between R_est a and R_gt S a, minimised over the
      discrete symmetries S (a 180 deg flip maps a to -a): the turn about a is not observable;
    - else: min over the group the discrete symmetries generate of angle(R_est, R_gt S)."""
    axes = axes or []
    if len(axes) >= 2:
        return 0.0
    if len(axes) == 1:
        a = axes[0]
        ang = lambda x, y: float(np.degrees(np.arccos(np.clip(x @ y, -1, 1))))  # noqa: E731
        return min(ang(R_est @ a, R_gt @ S @ a) for S in syms)
    return min(rot_err_deg(R_est, R_gt @ S) for S in _closure(syms))


def run_pair(scene_dir: Path, run_dir: Path, cfg: UpdateConfig, no_depth: bool, overlay: Path | None,
             embedder: str = "auto"):
    sc = load_scene(scene_dir)
    inter = json.loads((scene_dir / "gt" / "interaction.json").read_text())
    state = state_from_run(run_dir)
    # the stored instances' embeddings in the association's embedder (cached in the run after
    # the first time: not part of an update's time, like the run's segmentation)
    t, c = time.perf_counter(), time.process_time()
    state = with_embedder(state, resolve_embedder(embedder, state), scene=scene_dir)
    embed_s, embed_cpu_s = time.perf_counter() - t, time.process_time() - c
    view = sc.post_views[0]
    if no_depth:
        view = View(view.frame, view.rgb, view.camera, None, view.masks, view.name)
    t, c = time.perf_counter(), time.process_time()
    res = update_scene(state, view, cfg)
    dt, dc = time.perf_counter() - t, time.process_time() - c
    if overlay is not None:
        write_png(overlay, update_overlay(state, view, res))
    inst_obj, main = gt_mapping(state, sc)
    rem_o, dis_o = int(inter["removed_object"]), int(inter["displaced_object"])
    T_gt = np.asarray(inter["T_new_old"])
    gmap = sc.ground_truth.instance_maps.get(view.frame)
    dis_visible = bool(gmap is not None and np.count_nonzero(gmap == dis_o) >= 200)
    pred_removed = res.by_status("removed")
    pred_displaced = res.by_status("displaced")
    out = {
        "scene": scene_dir.parent.name, "time_s": dt, "cpu_s": dc, "embedder": state.embedder,
        "embed_run_s": embed_s, "embed_run_cpu_s": embed_cpu_s,
        "removed_found": main.get(rem_o) in pred_removed,
        # a removed object the initial segmentation never made an instance of cannot be reported
        "removed_has_instance": rem_o in main,
        "removed_pred": len(pred_removed), "removed_pred_true": sum(inst_obj.get(k) == rem_o for k in pred_removed),
        "displaced_visible": dis_visible, "displaced_has_instance": dis_o in main,
        "displaced_found": main.get(dis_o) in pred_displaced,
        "displaced_pred": len(pred_displaced),
        "displaced_pred_true": sum(inst_obj.get(k) == dis_o for k in pred_displaced),
        "static_flagged": sum(1 for r in res.instances if r.status in ("removed", "displaced")
                              and inst_obj.get(r.instance, -1) not in (rem_o, dis_o)),
        "statuses": {str(r.instance): [r.status, inst_obj.get(r.instance, -1), r.match] for r in res.instances},
        "displaced_main": main.get(dis_o, -1),
    }
    out.update(new_object_scores(sc, view, res, inst_obj, main, rem_o, dis_o))
    k = main.get(dis_o)
    if k is not None and k in pred_displaced:
        r = res.record(k)
        c = state.points_of(k).astype(np.float64).mean(axis=0)
        est, gt = r.T_world, T_gt
        pts = state.points_of(k).astype(np.float64)
        p_est, p_gt = pts @ est[:3, :3].T + est[:3, 3], pts @ gt[:3, :3].T + gt[:3, 3]
        gtp = sc.ground_truth.points[sc.ground_truth.point_labels == dis_o].astype(np.float64)
        syms, axes = symmetries(gtp), symmetry_axes(gtp)
        out.update(rot_err_deg=rot_err_deg(est[:3, :3], gt[:3, :3]),
                   sym_rot_err_deg=sym_rot_err_deg(est[:3, :3], gt[:3, :3], syms, axes), n_symmetries=len(syms),
                   n_sym_axes=len(axes),
                   adds_cm=100 * float(cKDTree(p_gt).query(p_est)[0].mean()),
                   trans_err_cm=100 * float(np.linalg.norm((est[:3, :3] @ c + est[:3, 3]) - (gt[:3, :3] @ c + gt[:3, 3]))),
                   gt_rot_deg=rot_err_deg(gt[:3, :3], np.eye(3)),
                   iou_before=r.iou_before, iou_after=r.iou_after, match=r.match,
                   stages=r.pose.stages if r.pose is not None else 0, iters=len(r.pose.trace) if r.pose is not None else 0)
    return out


NEW_IOU = 0.5
"""3D IoU (1 cm voxels) an added instance needs with a GT object's post-view points to count as it."""


def _voxels(p: np.ndarray, size: float = 0.01) -> set:
    return set(map(tuple, np.floor(np.asarray(p, np.float64) / size).astype(np.int64).tolist()))


def new_object_scores(sc, view, res, inst_obj: dict, main: dict, rem_o: int, dis_o: int) -> dict:
    """The new-object metrics of one pair (module docstring)."""
    added = getattr(res, "added", ())  # an older checkout's UpdateResult has none
    gmap = sc.ground_truth.instance_maps.get(view.frame)
    depth = sc.post_views[0].depth  # the post view's depth even for --no-depth runs (the reference)
    cam = view.camera
    n_obj = len(sc.ground_truth.objects)
    if gmap is None or depth is None:
        return {"new_gt": 0, "new_found": 0, "new_added": len(added), "new_right": 0, "new_dup": 0, "new_noise": 0,
                "displaced_readded": False, "new_detail": []}
    ok = np.isfinite(depth) & (depth > 0)

    def gt_vox(o: int) -> set:
        vs, us = np.nonzero((gmap == o) & ok)
        return _voxels(cam.pixels_to_world(us, vs, depth[vs, us]))

    removed = set(res.by_status("removed"))
    still = {o for k, o in inst_obj.items() if o >= 0 and k not in removed}  # objects that keep an instance
    new_gt = [o for o in range(n_obj) if o not in main and o != rem_o and np.count_nonzero(gmap == o) >= 200]
    found, right, dup, noise, readded, detail = set(), 0, 0, 0, False, []
    for a in added:
        uv, _ = cam.project(a.points.astype(np.float64))
        u, v = np.round(uv[:, 0]).astype(int), np.round(uv[:, 1]).astype(int)
        inb = (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
        lab = np.full(len(u), -1)
        lab[inb] = gmap[v[inb], u[inb]]
        o = int(np.bincount(lab + 1).argmax()) - 1
        o = o if o >= 0 and np.mean(lab == o) >= 0.5 else -1
        iou = 0.0
        if o >= 0:
            A, B = _voxels(a.points), gt_vox(o)
            iou = len(A & B) / max(len(A | B), 1)
        if o < 0:
            noise += 1
            kind = "noise"
        elif o in still:
            dup += 1
            kind = "duplicate"
        else:
            right += 1
            kind = "readded-displaced" if o == dis_o else "new"
            if iou >= NEW_IOU and o in new_gt:
                found.add(o)
            if o == dis_o and iou >= NEW_IOU:
                readded = True
        detail.append([a.instance, o, kind, round(iou, 3), len(a.points)])
    return {"new_gt": len(new_gt), "new_found": len(found), "new_added": len(added), "new_right": right,
            "new_dup": dup, "new_noise": noise, "displaced_readded": readded, "new_detail": detail}


def summarise(rows: list[dict]) -> dict:
    n = len(rows)
    rem_pred = sum(r["removed_pred"] for r in rows)
    dis_pred = sum(r["displaced_pred"] for r in rows)
    vis = [r for r in rows if r["displaced_visible"] and r["displaced_has_instance"]]
    pose = [r for r in rows if "rot_err_deg" in r]
    q = lambda xs, p: float(np.percentile(xs, p)) if xs else float("nan")  # noqa: E731
    rot = [r["rot_err_deg"] for r in pose]
    tr = [r["trans_err_cm"] for r in pose]
    return {
        "pairs": n,
        "removed_recall": sum(r["removed_found"] for r in rows) / n,
        "removed_recall_with_instance": (sum(r["removed_found"] for r in rows if r.get("removed_has_instance", True))
                                         / max(1, sum(r.get("removed_has_instance", True) for r in rows))),
        "removed_precision": sum(r["removed_pred_true"] for r in rows) / rem_pred if rem_pred else float("nan"),
        "displaced_recall_visible": sum(r["displaced_found"] for r in vis) / len(vis) if vis else float("nan"),
        "displaced_precision": sum(r["displaced_pred_true"] for r in rows) / dis_pred if dis_pred else float("nan"),
        "static_flagged_total": sum(r["static_flagged"] for r in rows),
        "rot_err_deg_median": q(rot, 50), "rot_err_deg_p90": q(rot, 90),
        "sym_rot_err_deg_median": q([r["sym_rot_err_deg"] for r in pose], 50),
        "sym_rot_err_deg_p90": q([r["sym_rot_err_deg"] for r in pose], 90),
        "trans_err_cm_median": q(tr, 50), "trans_err_cm_p90": q(tr, 90),
        "adds_cm_median": q([r["adds_cm"] for r in pose], 50), "adds_cm_p90": q([r["adds_cm"] for r in pose], 90),
        "iou_before_mean": float(np.mean([r["iou_before"] for r in pose])) if pose else float("nan"),
        "iou_after_mean": float(np.mean([r["iou_after"] for r in pose])) if pose else float("nan"),
        "time_s_median": q([r["time_s"] for r in rows], 50), "time_s_max": max(r["time_s"] for r in rows),
        "cpu_s_median": q([r["cpu_s"] for r in rows], 50), "cpu_s_max": max(r["cpu_s"] for r in rows),
        "new_objects_gt": sum(r.get("new_gt", 0) for r in rows),
        "new_objects_found": sum(r.get("new_found", 0) for r in rows),
        "new_added": sum(r.get("new_added", 0) for r in rows),
        "new_added_right": sum(r.get("new_right", 0) for r in rows),
        "new_added_duplicate": sum(r.get("new_dup", 0) for r in rows),
        "new_added_noise": sum(r.get("new_noise", 0) for r in rows),
        "displaced_unfitted": sum(1 for r in rows if r["displaced_visible"] and r["displaced_has_instance"]
                                  and r["statuses"].get(str(r.get("displaced_main", -1)), [""])[0] == "removed"),
        "displaced_readded": sum(bool(r.get("displaced_readded")) for r in rows),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("/tmp/bench_update"))
    ap.add_argument("--pairs", type=int, default=12, help="pairs, spread evenly over the presets")
    ap.add_argument("--seed0", type=int, default=100, help="first seed (seeds seed0.. per preset)")
    ap.add_argument("--no-depth", action="store_true", help="drop the post view's depth (RGB-only update)")
    ap.add_argument("--dof", choices=("se3", "yaw", "yaw-then-se3"), default="yaw")
    ap.add_argument("--no-verify", action="store_true", help="the paper's rule: IoU < tau_IoU is displaced")
    ap.add_argument("--no-early-exit", action="store_true", help="always run the fine stage")
    ap.add_argument("--min-fit-iou", type=float, default=ChangeConfig().min_fit_iou,
                    help="ChangeConfig.min_fit_iou (appearance matches below this fit are judged unmatched)")
    ap.add_argument("--embedder", default="auto",
                    help="mask embedder for S_semantic: auto (learned when installed) or a registry name")
    ap.add_argument("--no-depth-cues", action="store_true",
                    help="ChangeConfig.use_depth=False: the IoU test and the silhouette fit even with depth")
    ap.add_argument("--refine-registration", action="store_true",
                    help="PoseConfig.refine_registration: the paper's chamfer/photo stages after the depth registration")
    ap.add_argument("--photo-weight", type=float, default=PoseConfig().registration_photo_weight,
                    help="PoseConfig.registration_photo_weight (colour tie-break of the depth registration)")
    ap.add_argument("--tie-margin", type=float, default=PoseConfig().registration_tie_margin,
                    help="PoseConfig.registration_tie_margin")
    ap.add_argument("--yaw-starts", default=None,
                    help="PoseConfig.yaw_starts_deg as comma-separated degrees (default: the config's)")
    ap.add_argument("--tilt-starts", action="store_true",
                    help="PoseConfig.tilt_starts: tipped-over start placements for the RGB-only fit")
    ap.add_argument("--no-photo", action="store_true",
                    help="ChangeConfig.use_photo=False: without depth, the IoU test and rule 5's colour-and-mask test")
    ap.add_argument("--probe-iterations", type=int, default=PoseConfig().probe_iterations,
                    help="PoseConfig.probe_iterations (silhouette fit: steps per yaw start)")
    ap.add_argument("--coarse-iterations", type=int, default=PoseConfig().coarse.iterations,
                    help="PoseConfig.coarse.iterations (silhouette fit, probe steps included)")
    ap.add_argument("--fine-iterations", type=int, default=PoseConfig().fine.iterations,
                    help="PoseConfig.fine.iterations (silhouette fit)")
    ap.add_argument("--no-region-search", action="store_true",
                    help="ChangeConfig.search_unexplained=False: moved instances are registered to mask candidates only")
    ap.add_argument("--no-unfitted-presence", action="store_true",
                    help="ChangeConfig.unfitted_presence=False: a moved instance without a fit is removed")
    ap.add_argument("--no-new-objects", action="store_true",
                    help="ChangeConfig.new_objects=False: new masks are reported, not added")
    ap.add_argument("--registration-before", action="store_true",
                    help="session 6's registration options off: registration_keep_consistent=0, "
                         "fit_colour_weight=0, search_mask_pairs=False, registration_alternatives=0")
    ap.add_argument("--tag", default="", help="suffix of results_<tag>.json")
    a = ap.parse_args()
    cfg = UpdateConfig(change=ChangeConfig(verify=not a.no_verify, min_fit_iou=a.min_fit_iou,
                                           use_depth=not a.no_depth_cues, use_photo=not a.no_photo,
                                           search_unexplained=not a.no_region_search,
                                           unfitted_presence=not a.no_unfitted_presence,
                                           # an older checkout (the "before" of an A/B) has no such field
                                           **({"new_objects": not a.no_new_objects}
                                              if hasattr(ChangeConfig, "new_objects") else {}),
                                           **({"registration_keep_consistent": 0, "fit_colour_weight": 0.0,
                                               "search_mask_pairs": False, "registration_alternatives": 0}
                                              if a.registration_before else {})),
                       pose=replace(PoseConfig(), dof=a.dof, early_exit=not a.no_early_exit,
                                    refine_registration=a.refine_registration,
                                    registration_photo_weight=a.photo_weight,
                                    registration_tie_margin=a.tie_margin, tilt_starts=a.tilt_starts,
                                    probe_iterations=a.probe_iterations,
                                    coarse=replace(PoseConfig().coarse, iterations=a.coarse_iterations),
                                    fine=replace(PoseConfig().fine, iterations=a.fine_iterations),
                                    **({"yaw_starts_deg": tuple(float(x) for x in a.yaw_starts.split(","))}
                                       if a.yaw_starts else {})))
    a.out.mkdir(parents=True, exist_ok=True)
    rows = []
    for i in range(a.pairs):
        preset, seed = PRESETS[i % 3], a.seed0 + i // 3
        scene_dir, run_dir = make_pair(a.out, preset, seed)
        r = run_pair(scene_dir, run_dir, cfg, a.no_depth, a.out / f"overlay_{preset}_{seed}{'_' + a.tag if a.tag else ''}.png",
                     a.embedder)
        rows.append(r)
        print(json.dumps({k: (round(v, 3) if isinstance(v, float) else v) for k, v in r.items() if k != "statuses"}),
              flush=True)
    s = summarise(rows)
    (a.out / f"results{'_' + a.tag if a.tag else ''}.json").write_text(json.dumps({"summary": s, "pairs": rows}, indent=1))
    print("\n| metric | value |\n| --- | --- |")
    for k, v in s.items():
        print(f"| {k} | {v:.3f} |" if isinstance(v, float) else f"| {k} | {v} |")


if __name__ == "__main__":
    main()
