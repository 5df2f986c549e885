"""Every ``refine.absorb_fragments`` decision on generated scenes, with its features and the ground
truth's verdict (session 10, docs/benchmark/strict-iou.md "Session 10: absorb errors").

``segment`` runs with the default config; the pipeline's absorption records, per absorbed instance
(the vote before each merge is kept, ``logged_absorb``): its won fraction and the share the absorber won,
its raw points and their ratio to the absorber's, its masks (count, views, largest pixel area against
the absorber's median mask), the mean / max S_semantic and S_spatial of its masks to the absorber's,
the GT object of most of its points, and the owners of its masks (``ap50_misses.mask_owner``). Kind:
``wrong`` when most of its masks are another object's than most of the absorber's; ``mixed`` when its
masks are the absorber's object's but most of its points are another object's; else ``right``.

    .venv/bin/python benchmarks/absorb_decisions.py --seeds 2 3 10 11 --difficulties hard \
        --cache /tmp/bench_cache /tmp/s9/cache14

Each scene is read from the first cache that holds it (none: it is generated into the first).
Seeds 6-9 and 18-21 are the lead's held-out: refused.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import clutt3r_core.pipeline as pipeline  # noqa: E402
from ap50_misses import mask_owner, point_gt  # noqa: E402  (this folder's sibling script)
from clutt3r_core.config import SegmentConfig  # noqa: E402
from clutt3r_core.evaluation.runner import _load_prepared, _scene_file, synth_suite  # noqa: E402
from clutt3r_core.segmentation import refine  # noqa: E402

LOG: list[dict] = []


def _mean_max(m: np.ndarray) -> tuple[float | None, float | None]:
    fin = np.isfinite(m)
    return (float(m[fin].mean()), float(m[fin].max())) if fin.any() else (None, None)


def logged_absorb(grouping, vote, occupancy, sv_counts, s_spatial, s_semantic, revote, cfg):
    """``refine.absorb_fragments`` itself, recording each absorption: the vote before each merge is
    kept (the first one, then each revote), and each absorb ``MergeStep`` (groups a -> b) is read
    against it."""
    votes = [vote]

    def kept(groups):
        votes.append(revote(groups))
        return votes[-1]

    out = refine.absorb_fragments(grouping, vote, occupancy, sv_counts, s_spatial, s_semantic, kept, cfg)
    groups = [tuple(g) for g in grouping.groups]
    steps = [m for m in out[0].merges[len(grouping.merges):] if m.stage == refine.ABSORB_STAGE]
    for m, v in zip(steps, votes):
        won, best, share = refine.won_fractions(tuple(groups), occupancy, sv_counts, v)
        lab = v.sv_label
        pts = np.bincount(lab[lab >= 0], weights=np.asarray(sv_counts, np.float64)[lab >= 0], minlength=len(won))
        gi, gj = groups.index(tuple(m.a)), groups.index(tuple(m.b))
        i = int(np.flatnonzero(np.asarray(v.instance_group) == gi)[0])
        a, b = groups[gi], groups[gj]
        cross = np.ix_(list(a), list(b))
        se, sp = _mean_max(s_semantic[cross]), _mean_max(s_spatial[cross])
        LOG.append(dict(won=float(won[i]), share=float(share[i]), pts=float(pts[i]), pts_nb=float(pts[best[i]]),
                        a=list(a), b=list(b), se_mean=se[0], se_max=se[1], sp_mean=sp[0], sp_max=sp[1],
                        sv_a=np.flatnonzero(lab == i), sv_b=np.flatnonzero(lab == best[i])))
        groups = [g for k, g in enumerate(groups) if k not in (gi, gj)] + [tuple(sorted(a + b))]
    return out


def decisions(scene, cfg: SegmentConfig) -> list[dict]:
    LOG.clear()
    gt = scene.ground_truth
    n_obj = len(gt.objects)
    seg = pipeline.segment(scene, cfg, progress=False)
    pg = point_gt(seg.points, gt)
    w = seg.counts.astype(np.float64)
    owner, comp = mask_owner(scene, seg.trace, n_obj)
    area = comp.sum(axis=1)
    view = seg.trace.nodes.view

    def gt_of(svs: np.ndarray) -> tuple[int, float]:
        sel = np.isin(seg.sv_labels, svs)
        h = np.bincount(np.where(pg[sel] >= 0, pg[sel], n_obj), weights=w[sel], minlength=n_obj + 1)
        g = int(np.argmax(h))
        return (g if g < n_obj else -1), float(h[g] / max(h.sum(), 1.0))

    rows = []
    for d in LOG:
        ga, fa = gt_of(d["sv_a"])
        gb, _ = gt_of(d["sv_b"])
        oa = [int(owner[u]) for u in d["a"] if owner[u] >= 0]
        ob = [int(owner[u]) for u in d["b"]]
        maj_a = max(set(oa), key=oa.count) if oa else -1
        maj_b = max(set(ob), key=ob.count)
        kind = ("wrong" if maj_a >= 0 and maj_a != maj_b else "mixed" if ga >= 0 and ga != gb else "right")
        rows.append(dict(won=round(d["won"], 3), share=round(d["share"], 2), pts=int(d["pts"]),
                         ratio=round(d["pts"] / d["pts_nb"], 3), masks=len(d["a"]),
                         views=len(set(view[d["a"]].tolist())),
                         area_ratio=round(float(area[d["a"]].max() / np.median(area[d["b"]])), 3),
                         se_mean=d["se_mean"], se_max=d["se_max"], sp_mean=d["sp_mean"], sp_max=d["sp_max"],
                         gt=ga, gt_share=round(fa, 2), gt_absorber=gb,
                         mask_owners=[int(owner[u]) for u in d["a"]], absorber_owner=maj_b, kind=kind))
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[2, 3])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--depth-noise", default="realsense")
    ap.add_argument("--cache", nargs="+", default=["/tmp/bench_cache"])
    args = ap.parse_args()
    if any(6 <= s <= 9 or 18 <= s <= 21 for s in args.seeds):
        raise SystemExit("seeds 6-9 and 18-21 are the lead's held-out")
    pipeline.absorb_fragments = logged_absorb  # the pipeline calls it by this module-level name
    allrows = []
    for d in args.difficulties:
        for s in args.seeds:
            spec = synth_suite(1, [d], depth_noise=args.depth_noise, seed0=s)[0]
            cache = next((c for c in args.cache if _scene_file(c, spec).is_file()), args.cache[0])
            for r in decisions(_load_prepared(cache, spec).scene, SegmentConfig()):
                r = dict(scene=spec.name, **r)
                print(json.dumps(r), flush=True)
                allrows.append(r)
    feats = ("pts", "ratio", "won", "share", "masks", "views", "area_ratio", "se_mean", "se_max", "sp_mean", "sp_max")
    print("\n| kind | n | " + " | ".join(feats) + " |  (min / median / max)")
    print("|---|---|" + "---|" * len(feats))
    for k in ("right", "mixed", "wrong"):
        rs = [r for r in allrows if r["kind"] == k]
        if rs:
            cells = []
            for f in feats:
                v = np.array([np.nan if r[f] is None else r[f] for r in rs], float)
                cells.append(f"{np.nanmin(v):.3g} / {np.nanmedian(v):.3g} / {np.nanmax(v):.3g}")
            print(f"| {k} | {len(rs)} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
