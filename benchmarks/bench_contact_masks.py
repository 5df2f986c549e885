"""Does the per-point mask test separate the contact fill's object walls from floor noise? (session 9)

For each scene, ``segment`` runs with the contact fill on (off by default; on as measured in session 9:
contact 2 mm, fill 4-12 mm above each object's own support level) and ``contact_labels`` is called again on its
inputs with the fill's mask test off, so every fill candidate is known. For each, ``point_mask_votes`` counts
the views that see it and those that put it inside the masks of the instance it joins; the same
for that instance's own points (labelled before the fill) in the same height band. Prints one JSON
line per scene: counts, the mean share inside of filled and own points, how many filled points
each ``--shares`` threshold keeps, and on generated scenes which filled points are the instance's
object by the ground truth (nearest GT point's label against the instance's majority GT label):

    .venv/bin/python benchmarks/bench_contact_masks.py /work/shared/data/clutt3r-samples/sample_seq4/data \
        --picture /tmp/seq4_fill.png
    .venv/bin/python benchmarks/bench_contact_masks.py --seeds 2 3 --margins 0 1 2 --shares 0.5 0.3

``--picture`` (one scene) draws the filled points over the first view: kept by the test at
``--shares``' and ``--margins``' first values green, refused red, the instance's own points in the band blue.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import replace

import numpy as np

import clutt3r_core.pipeline as pipeline
from clutt3r_core.config import SegmentConfig, with_fields
from clutt3r_core.segmentation.contact_masks import point_mask_votes

FILL = {"refine.contact_height": 0.002, "refine.contact_fill_low": 0.004, "refine.contact_fill_high": 0.012,
        # a share that no seen point fails: the pipeline builds the views; the record below
        # re-runs the rule without the test
        "refine.contact_fill_mask_share": 1e-9}


def record_contact():
    """Wrap the pipeline's ``contact_labels``: keep its inputs and the untested fill's result."""
    orig = pipeline.contact_labels
    box = {}

    def wrapped(points, normals, instance, k, plane, cfg, views=None):
        box.update(points=np.asarray(points), normals=normals, before=np.asarray(instance).copy(), k=k,
                   plane=plane, cfg=cfg, views=views,
                   untested=orig(points, normals, instance, k, plane, replace(cfg, contact_fill_mask_share=0.0)))
        return orig(points, normals, instance, k, plane, cfg, views)

    pipeline.contact_labels = wrapped
    return box


def evidence(scene, fields: dict, shares: list[float], depth_tol: float, margins: list[int]) -> tuple[dict, dict]:
    box = record_contact()
    seg = pipeline.segment(scene, with_fields(SegmentConfig(), {**FILL, **fields}), progress=False)
    p, before, res, views = box["points"], box["before"], box["untested"], box["views"]
    pl = np.asarray(box["plane"], np.float64)
    h = p @ pl[:3] + pl[3]
    cfg = box["cfg"]
    filled = np.flatnonzero(res.filled)
    lab_f = res.instance[filled]
    vf = point_mask_votes(p[filled], lab_f, views, depth_tol)
    rel = np.where(before >= 0, h - res.level[np.maximum(before, 0)], np.nan)
    own = np.flatnonzero((before >= 0) & (rel >= cfg.contact_fill_low) & (rel < cfg.contact_fill_high))
    vo = point_mask_votes(p[own], before[own], views, depth_tol)
    high = np.flatnonzero((before >= 0) & (rel >= 0.04))
    vh = point_mask_votes(p[high], before[high], views, depth_tol)

    def summary(v):
        s = v.share()
        return dict(n=len(s), seen0=int((v.seen == 0).sum()), seen_median=float(np.median(v.seen)) if len(s) else 0,
                    share_mean=round(float(np.nanmean(s)), 3) if np.isfinite(s).any() else None)

    out = dict(scene=scene.name, object_points=int((before >= 0).sum()), filled=summary(vf), own_band=summary(vo),
               own_above_40mm=summary(vh))
    keep = {}
    for m in margins:
        vm = point_mask_votes(p[filled], lab_f, views, depth_tol, m)
        out[f"filled_share_m{m}"] = round(float(np.nanmean(vm.share())), 3) if len(filled) else None
        vo_m = point_mask_votes(p[own], before[own], views, depth_tol, m)
        out[f"own_band_share_m{m}"] = round(float(np.nanmean(vo_m.share())), 3) if len(own) else None
        for s in shares:
            keep[s, m] = (vm.seen > 0) & (vm.inside >= s * vm.seen)
            out[f"kept@{s},m{m}"] = int(keep[s, m].sum())
    gt = scene.ground_truth
    if gt is not None and len(filled):
        from clutt3r_core.normals import knn_query, knn_tree

        tree = knn_tree(np.asarray(gt.points, np.float64))
        _, j = knn_query(tree, p.astype(np.float64), 1)
        g = np.asarray(gt.point_labels)[j[:, 0]]
        maj = np.full(box["k"], -2)
        for k in range(box["k"]):
            v, c = np.unique(g[before == k], return_counts=True)
            if len(v):
                maj[k] = v[np.argmax(c)]
        right = g[filled] == maj[lab_f]
        out["filled_right_by_gt"] = int(right.sum())
        for (s, m), kk in keep.items():
            out[f"kept@{s},m{m}_right"] = f"{int((kk & right).sum())}/{int(kk.sum())}"
    return out, dict(seg=seg, points=p, filled=filled, keep=keep.get((shares[0], margins[0])), own=own)


def picture(scene, d: dict, path: str) -> None:
    from PIL import Image, ImageDraw

    v = sorted(scene.initial_views, key=lambda v: v.frame)[0]
    img = Image.fromarray(np.asarray(v.rgb)).convert("RGB")
    draw = ImageDraw.Draw(img)
    cam = v.camera
    r = max(1, cam.width // 400)

    def dots(pts, colour):
        uv, z = cam.project(pts)
        for a, b in uv[z > 1e-6]:
            draw.ellipse([a - r, b - r, a + r, b + r], fill=colour)

    p = d["points"]
    dots(p[d["own"]], (60, 120, 255))
    dots(p[d["filled"][~d["keep"]]], (255, 40, 40))
    dots(p[d["filled"][d["keep"]]], (40, 255, 40))
    img.save(path)
    print("picture:", path, "(green kept, red refused, blue own points in the band)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", help="scene folders (real samples)")
    ap.add_argument("--seeds", type=int, nargs="*", default=[])
    ap.add_argument("--difficulties", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--shares", type=float, nargs="+", default=[0.5, 0.3, 0.7])
    ap.add_argument("--depth-tol", type=float, default=0.005)
    ap.add_argument("--margins", type=int, nargs="+", default=[0], help="pixels (the first draws the picture)")
    ap.add_argument("--variant", default="", help="FIELD=VALUE,... over the fill (JSON values)")
    ap.add_argument("--picture", default="")
    ap.add_argument("--cache", default="/tmp/bench_cache")
    args = ap.parse_args()
    from bench_config_ab import parse_variant  # this folder's sibling script

    fields = parse_variant("v:" + args.variant)[1]
    scenes = []
    for path in args.scenes:
        from clutt3r_core.io import load_scene

        scenes.append(lambda path=path: load_scene(path))
    if args.seeds:
        from clutt3r_core.evaluation.runner import _load_prepared, synth_suite

        for s in synth_suite(max(args.seeds) + 1, args.difficulties, depth_noise="realsense"):
            if int(s.name[-4:]) in args.seeds:
                scenes.append(lambda s=s: _load_prepared(args.cache, s).scene)
    for make in scenes:
        scene = make()
        out, d = evidence(scene, fields, args.shares, args.depth_tol, args.margins)
        print(json.dumps(out), flush=True)
        if args.picture:
            picture(scene, d, args.picture)


if __name__ == "__main__":
    main()
