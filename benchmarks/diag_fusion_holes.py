"""Where the remaining holes are: what the raw data held in each GT object cell with no result point (session 9).

Diagnostic of docs/benchmark/strict-iou.md, "Session 9: the holes". For each generated scene (RealSense-like
depth), ``segment`` runs with the default; every hole cell (a 10 mm GT object cell with no point of the
result, rim voxels included: the breakdown's ``hole``) gets the best fate of the fusion's moved points that
land in it (the surface estimate and its keep rule recomputed as ``surface._snap_and_filter`` does):
a kept or rim voxel (none expected), a lone moved point from a voxel of one raw point next to kept voxels
(dropped by the count rule), a lone moved point with no kept neighbour, a lone unmoved point with no kept
neighbour; else "raw points moved out of the cell by the estimate" when raw points lay in it before the
moves, else "no raw point" (then split by what the views show at the cell's GT points: depth within 15 mm
in some view, depth NaN in some view and occluded in the rest, see-through, occluded everywhere). Also per
category: GT points per hole cell and their distance to the nearest result point; and for the lone moved
voxels next to kept ones, how many views' depth passes within 2.5 / 4 mm of their centre, by hole cells
filled and new off-GT cells near objects (within 2 cells of a GT object cell):

    .venv/bin/python benchmarks/diag_fusion_holes.py --seeds 2 3

Scenes are cached under --cache (default /tmp/bench_cache). Seeds >= 6 are refused (held out).
"""

import argparse, json, sys, time
import numpy as np
from clutt3r_core.config import SegmentConfig
from clutt3r_core.evaluation.metrics import EVAL_VOXEL, voxelize_labels
from clutt3r_core.evaluation.runner import _load_prepared, synth_suite
from clutt3r_core.pipeline import segment
from clutt3r_core.pointcloud import PointCloudConfig, _backproject_strided, auto_stride, _voxel_keys, _group_keys
from clutt3r_core.surface import snap_to_surface, surface_params, _kept_neighbours, _SmoothedDepth

ap = argparse.ArgumentParser()
ap.add_argument("--seeds", type=int, nargs="+", default=[2])
ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
ap.add_argument("--cache", default="/tmp/bench_cache")
args = ap.parse_args()
if max(args.seeds) >= 6:
    raise SystemExit("seeds 6-9 are held out")
specs = [s for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise="realsense") if int(s.name[-4:]) in args.seeds]

def cellkey(p, v=EVAL_VOXEL):
    q = np.floor(np.asarray(p, np.float64) / v).astype(np.int64)
    return (q[:, 0] + 100000) * 10**10 + (q[:, 1] + 100000) * 10**5 + (q[:, 2] + 50000)  # unique pack

for spec in specs:
    scene = _load_prepared(args.cache, spec).scene
    gt = scene.ground_truth
    cfg = SegmentConfig()
    seg = segment(scene, cfg, progress=False)
    pc = cfg.pointcloud
    views = sorted(scene.initial_views, key=lambda v: v.frame)
    strides = [pc.pixel_stride or auto_stride(v.camera.height, v.camera.width) for v in views]
    Ps, vid = [], []
    for i, (v, s) in enumerate(zip(views, strides)):
        pw, pix = _backproject_strided(v, s, pc)
        Ps.append(pw); vid.append(np.full(len(pw), i, np.int16))
    P = np.concatenate(Ps); vid = np.concatenate(vid)
    offsets = np.concatenate([[0], np.cumsum([len(p) for p in Ps])])
    zp = np.empty(len(P), np.float32)
    for v, view in enumerate(views):
        T = view.camera.T_camera_world; sl = slice(offsets[v], offsets[v + 1])
        zp[sl] = P[sl] @ T[2, :3].astype(np.float32) + np.float32(T[2, 3])
    params = surface_params(pc)
    sn = snap_to_surface(views, P, strides, params, point_depth=zp)
    keys, _, ext = _voxel_keys(sn.points, pc.voxel_size, pad=1)
    inverse, counts = _group_keys(keys, ext)
    nv = len(counts)
    nmoved = np.bincount(inverse[sn.moved], minlength=nv)
    trusted = np.bincount(inverse[sn.trusted], minlength=nv) > 0
    kept = (counts >= pc.surface_min_points) | trusted
    lone = ~kept & (counts == 1)
    kn = np.zeros(nv, np.int64)
    cand = np.flatnonzero(lone)
    kn[cand] = _kept_neighbours(keys, ext, inverse, kept, cand)
    rim = lone & (nmoved == 0) & (kn >= pc.surface_rim_neighbours)
    # the keep rule above is surface._snap_and_filter's, recomputed: it must find the fusion's rim voxels
    assert int(rim.sum()) == seg.trace.surface.rim, (int(rim.sum()), seg.trace.surface.rim)
    # voxel fate: 0 kept, 1 rim, 2 lone moved untrusted (count rule) w/ kept nbr, 3 lone moved no kept nbr,
    # 4 lone unmoved no kept nbr
    fate = np.full(nv, -1)
    fate[kept] = 0; fate[rim] = 1
    fate[lone & (nmoved == 1) & (kn >= 1)] = 2
    fate[lone & (nmoved == 1) & (kn == 0)] = 3
    fate[lone & (nmoved == 0) & (kn == 0)] = 4
    assert (fate >= 0).all(), np.unique(counts[fate < 0])
    pfate = fate[inverse]
    # GT object cells and hole cells
    g = voxelize_labels(gt.points, gt.point_labels, EVAL_VOXEL)
    gk = (g.cells[:, 0] + 100000) * 10**10 + (g.cells[:, 1] + 100000) * 10**5 + (g.cells[:, 2] + 50000)
    obj = g.labels >= 0
    seg_cells = np.unique(cellkey(seg.points))
    hole = obj & ~np.isin(gk, seg_cells)
    hk = gk[hole]
    # per hole cell: moved points landing in it, raw points originally in it
    mk = cellkey(sn.points); rk = cellkey(P)
    cat = {}
    in_m = np.isin(mk, hk); in_r = np.isin(rk, hk)
    # best fate per cell among moved points landing there (lowest fate code = most kept)
    best = {}
    for c, f in zip(mk[in_m], pfate[in_m]):
        best[c] = min(best.get(c, 9), f)
    raw_cells = set(rk[in_r].tolist())
    names = {0: "kept voxel (?)", 1: "rim voxel (?)", 2: "lone moved pt, 1-raw-pt voxel, kept nbr (count rule)",
             3: "lone moved pt, no kept nbr", 4: "lone unmoved pt, no kept nbr"}
    rows = {}
    # for hole cells with no points: visibility analysis of their GT points
    for c in hk:
        if c in best:
            k = names[best[c]]
        elif c in raw_cells:
            k = "raw points moved out of the cell by the estimate"
        else:
            k = "no raw point"
        rows[k] = rows.get(k, 0) + 1
    # nearest kept-voxel distance for dropped lone voxels in hole cells (in voxels, chebyshev), up to 3
    # Gt points of "no raw point" cells: per view, depth NaN / occluded / seen / outside
    nor = [c for c in hk if c not in best and c not in raw_cells]
    gpk = cellkey(gt.points)
    sel = np.isin(gpk, np.array(nor, np.int64)) & (gt.point_labels >= 0)
    gp = np.asarray(gt.points, np.float64)[sel]; gpc = gpk[sel]
    stat = np.zeros((len(gp), 5), int)  # nan, occluded, seen, outside, behind
    for v in views:
        cam = v.camera; T = cam.T_camera_world
        pcam = gp @ T[:3, :3].T + T[:3, 3]
        z = pcam[:, 2]
        u = np.rint(pcam[:, 0] * cam.fx / z + cam.cx).astype(int); r = np.rint(pcam[:, 1] * cam.fy / z + cam.cy).astype(int)
        ins = (z > 0) & (u >= 0) & (u < cam.width) & (r >= 0) & (r < cam.height)
        d = np.full(len(gp), np.nan)
        d[ins] = v.depth[r[ins], u[ins]]
        stat[~ins, 3] += 1
        stat[ins & np.isnan(d), 0] += 1
        stat[ins & ~np.isnan(d) & (d < z - 0.015), 1] += 1
        stat[ins & ~np.isnan(d) & (np.abs(d - z) <= 0.015), 2] += 1
        stat[ins & ~np.isnan(d) & (d > z + 0.015), 4] += 1
    # per cell: any view with depth there (seen), else any NaN view, else occluded-only
    per = {}
    for c in np.unique(gpc):
        m = gpc == c
        s = stat[m].sum(axis=0)
        k = "seen by >=1 view (depth within 15 mm)" if s[2] else "see-through (depth behind) in >=1 view" if s[4] else ("depth NaN in >=1 view, occluded in the rest" if s[0] else "occluded / outside in every view")
        per[k] = per.get(k, 0) + 1
    # whole-scene fate counts of dropped voxels, and where they lie w.r.t GT cells
    vk = cellkey(sn.points)
    vox_cell = np.empty(nv, np.int64); vox_cell[inverse] = vk
    gt_obj_cells = gk[obj]; gt_any = gk
    fate_where = {}
    for f in (1, 2, 3, 4):
        vv = np.flatnonzero(fate == f)
        cc = vox_cell[vv]
        fate_where[names[f]] = dict(n=len(vv), in_hole_cell=int(np.isin(cc, hk).sum()),
                                    in_covered_obj_cell=int((np.isin(cc, gt_obj_cells) & ~np.isin(cc, hk)).sum()),
                                    in_gt_table_cell=int((np.isin(cc, gt_any) & ~np.isin(cc, gt_obj_cells)).sum()),
                                    off_gt=int((~np.isin(cc, gt_any)).sum()))
    # GT points per hole cell, and their distance to the nearest result point, by category
    from scipy.spatial import cKDTree
    tree = cKDTree(np.asarray(seg.points, np.float64))
    gall = np.asarray(gt.points, np.float64); gallk = cellkey(gall)
    ext_stats = {}
    catof = {}
    for c in hk:
        catof[c] = names[best[c]] if c in best else ("moved out" if c in raw_cells else "no raw point")
    hsel = np.isin(gallk, hk) & (gt.point_labels >= 0)
    dd = tree.query(gall[hsel])[0]
    hc = gallk[hsel]
    for k in set(catof.values()):
        cs = np.array([c for c in hk if catof[c] == k], np.int64)
        m = np.isin(hc, cs)
        npts = np.unique(hc[m], return_counts=True)[1]
        ext_stats[k] = dict(cells=len(cs), gt_pts_per_cell_median=float(np.median(npts)), cells_le3_gt_pts=int((npts <= 3).sum()),
                            dist_mm_median=round(1000 * float(np.median(dd[m])), 2), dist_mm_p90=round(1000 * float(np.percentile(dd[m], 90)), 2))
    allobj = np.isin(gallk, gk[obj]) & (gt.point_labels >= 0)
    ext_stats["all GT object cells"] = dict(gt_pts_per_cell_median=float(np.median(np.unique(gallk[allobj], return_counts=True)[1])))
    # moved-out cells: the moves of their raw points, and the fate of the voxel they landed in
    mo = np.array([c for c in hk if catof[c] == "moved out"], np.int64)
    mm = np.isin(rk, mo)
    mv = np.linalg.norm(sn.points[mm] - P[mm], axis=1)
    ext_stats["moved out: raw points"] = dict(n=int(mm.sum()), move_mm_median=round(1000 * float(np.median(mv)), 2) if mm.any() else None,
                                              landed_fate={names[f]: int((pfate[mm] == f).sum()) for f in range(5)})
    # lone moved voxels next to kept ones (the count rule's): views whose depth passes near their centre
    one = np.empty(nv, np.intp); one[inverse] = np.arange(len(inverse))
    cv = np.flatnonzero(fate == 2)
    cpts = sn.points[one[cv]].astype(np.float64)
    cen = (np.floor(cpts / pc.voxel_size) + 0.5) * pc.voxel_size
    nag = {t: np.zeros(len(cen), int) for t in (0.0025, 0.004)}
    for view, s in zip(views, strides):
        zs = np.asarray(view.depth, np.float32)[::s, ::s]
        sd = _SmoothedDepth(np.where((zs >= params.min_depth) & (zs <= params.max_depth), zs, np.nan), params.smooth_px, params.edge_std)
        cam = view.camera; T = cam.T_camera_world
        q = cen @ T[:3, :3].T + T[:3, 3]; z = q[:, 2]
        col = (q[:, 0] * cam.fx / z + cam.cx) / s; row = (q[:, 1] * cam.fy / z + cam.cy) / s
        hh, ww = sd.z.shape
        ins = np.flatnonzero((z > params.min_depth) & (col > -0.5) & (col < ww - 0.5) & (row > -0.5) & (row < hh - 0.5))
        d = sd.at(row[ins], col[ins]) - z[ins]
        for t in nag:
            nag[t][ins[np.abs(d) <= t]] += 1
    oc = g.cells[obj]
    near = np.unique(np.concatenate([cellkey((oc + np.array([dx, dy, dz]) + 0.5) * EVAL_VOXEL)
                                     for dx in range(-2, 3) for dy in range(-2, 3) for dz in range(-2, 3)]))
    ck = cellkey(cpts)
    c_hole = np.isin(ck, hk)
    c_new_off = ~np.isin(ck, gk) & np.isin(ck, near) & ~np.isin(ck, seg_cells)
    agree = {"any": dict(voxels=len(cv), hole_cells=len(np.unique(ck[c_hole])), new_offgt_cells_near_obj=len(np.unique(ck[c_new_off])))}
    for t, n in nag.items():
        for m in (1, 2, 3):
            sel = n >= m
            agree[f"{t * 1000:.1f}mm_views>={m}"] = dict(voxels=int(sel.sum()), hole_cells=len(np.unique(ck[sel & c_hole])),
                                                         new_offgt_cells_near_obj=len(np.unique(ck[sel & c_new_off])))
    out = dict(scene=spec.name, gt_obj_cells=int(obj.sum()), holes=int(hole.sum()), by_fate=rows,
               no_raw_point_visibility=per, dropped_voxels=fate_where, moved_frac=float(sn.moved.mean()), ext=ext_stats, lone_moved_agreement=agree)
    print(json.dumps(out), flush=True)
