"""Split objects against touching objects: what the two groups of each pair look like (session 10).

For each generated scene, ``segment`` runs with the default config. A *split* is a GT object with
a second instance of its own (mostly this object's points, >= 10 % of them); a *touch* is two
objects whose main instances have points within 8 mm. For the two groups behind each pair, one
JSON line: masks (nA, nB), views they share, mean / max S_spatial over their cross-view mask
pairs (sp_mean is what ``grouping.reunion_tau`` reads), the fraction of those pairs above 0,
mean S_semantic, shared views whose two masks have a common tree ancestor, and ``cont``: the
largest pixel intersection over the smaller mask of their two masks in a shared view
(``grouping.reunion_max_contain``'s measure). docs/benchmark/strict-iou.md, "Session 10: splits":

    .venv/bin/python benchmarks/split_pairs.py --seeds 14 15 16 17 --difficulties hard --cache /tmp/s9/cache14

Seeds >= 6 other than the ones named are the lead's held-out: name fresh seeds explicitly.
"""
import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree
sys.path.insert(0, str(Path(__file__).parent))  # this folder's sibling script
from ap50_misses import mask_owner, segment_and_match
from clutt3r_core.config import SegmentConfig
from clutt3r_core.evaluation.runner import synth_suite


def ancestors(parent, i):
    out = []
    while parent[i] >= 0:
        i = int(parent[i]); out.append(i)
    return out


def mask_px(vmasks, mid):
    m = vmasks
    k = m.index_of(int(mid))
    return m.bits[:, k], np.bincount(m.codes.reshape(-1), minlength=len(m.bits))


def pair_feats(tr, A, B, views=None):
    nodes = tr.nodes
    A = list(A); B = list(B)
    sp = tr.s_spatial[np.ix_(A, B)]; se = tr.s_semantic[np.ix_(A, B)]
    d = np.isfinite(sp)
    va = set(nodes.view[A].tolist()); vb = set(nodes.view[B].tolist())
    shared = va & vb
    # shared views: do the two masks have a common tree ancestor (a whole-object mask)?
    common = 0
    cont = 0.0
    for v in shared:
        a = [i for i in A if nodes.view[i] == v][0]; b = [i for i in B if nodes.view[i] == v][0]
        if views is not None:
            ba, cnt = mask_px(views[v].masks, nodes.mask_id[a]); bb, _ = mask_px(views[v].masks, nodes.mask_id[b])
            inter = cnt[ba & bb].sum(); cont = max(cont, inter / max(1, min(cnt[ba].sum(), cnt[bb].sum())))
        if set(ancestors(nodes.parent, a)) & set(ancestors(nodes.parent, b)):
            common += 1
    return dict(nA=len(A), nB=len(B), shared=len(shared), views=len(va | vb),
                sp_mean=round(float(sp[d].mean()), 3) if d.any() else None,
                sp_max=round(float(sp[d].max()), 3) if d.any() else None,
                sp_pos=round(float((sp[d] > 0).mean()), 2) if d.any() else None,
                sem=round(float(se[d].mean()), 3) if d.any() else None,
                common_anc=common, cont=round(float(cont), 2))


def run(spec, cache, cfg):
    scene, seg, iou, pid, gid, pg, comp, dom = segment_and_match(spec, cache, cfg)
    gt = scene.ground_truth
    n_obj = len(gt.objects)
    tr = seg.trace
    w = seg.counts.astype(float); inst = seg.instance; n_inst = len(seg.scores)
    tot = np.bincount(np.where(pg < 0, n_obj, pg), weights=w, minlength=n_obj + 1)
    groups = tr.grouping.groups; ig = tr.vote.instance_group
    owner, _ = mask_owner(scene, tr, n_obj)
    vws = sorted(scene.initial_views, key=lambda v: v.frame)
    rows = []
    # adjacency of instances: point within 8 mm
    kd = [cKDTree(seg.points[inst == p]) if (inst == p).any() else None for p in range(n_inst)]
    def touch(p, q):
        if kd[p] is None or kd[q] is None: return False
        dd, _ = kd[q].query(seg.points[inst == p], k=1, distance_upper_bound=0.008)
        return int(np.isfinite(dd).sum())
    for g in range(n_obj):
        own = [p for p in range(n_inst) if dom[p] == g]
        if len(own) < 2: continue
        own.sort(key=lambda p: -comp[p, g])
        best = float(iou[list(pid).index(own[0]), list(gid).index(g)]) if g in gid else 0
        for q in own[1:]:
            share = comp[q, g] / tot[g]
            if share < 0.1: continue
            A, B = groups[int(ig[own[0]])], groups[int(ig[q])]
            f = pair_feats(tr, A, B, vws)
            f.update(kind="split", scene=spec.name, obj=g, name=gt.objects[g].name if hasattr(gt.objects[g], "name") else "",
                     best_iou=round(best, 2), share1=round(comp[own[0], g] / tot[g], 2), share2=round(share, 2),
                     touch=touch(own[0], q), ownA=int((owner[list(A)] == g).sum()), ownB=int((owner[list(B)] == g).sum()))
            rows.append(f)
    # touching pairs of two objects' main instances
    main = {}
    for p in range(n_inst):
        g = dom[p]
        if g >= 0 and (g not in main or comp[p, g] > comp[main[g], g]): main[g] = p
    ms = sorted(main.items())
    for i in range(len(ms)):
        for j in range(i + 1, len(ms)):
            (g, p), (h, q) = ms[i], ms[j]
            t = touch(p, q)
            if not t: continue
            f = pair_feats(tr, groups[int(ig[p])], groups[int(ig[q])], vws)
            f.update(kind="touch", scene=spec.name, obj=(int(g), int(h)), touch=t)
            rows.append(f)
    return rows


if __name__ == "__main__":
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+"); ap.add_argument("--difficulties", nargs="+")
    ap.add_argument("--cache"); a = ap.parse_args()
    lo, hi = min(a.seeds), max(a.seeds)
    specs = [s for s in synth_suite(hi - lo + 1, a.difficulties, seed0=lo) if int(s.name[-4:]) in a.seeds]
    for s in specs:
        for r in run(s, a.cache, SegmentConfig()):
            print(json.dumps(r, default=int), flush=True)
