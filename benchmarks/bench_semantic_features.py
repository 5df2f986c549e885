"""S_semantic from learned features (issue 17): calibrate tau_sem for ``imagenet-minilm``
and check that segmenting with it does not hurt.

Usage:
    .venv/bin/python benchmarks/bench_semantic_features.py [--work /tmp/clutt3r-bench-query]
        [--presets easy intermediate hard] [--seeds 10 11] [--samples] [--out FILE]

1. Separation: for every pair of non-background leaves of different views whose masks
   are mostly (>= 80 % of pixels) one GT object, S_semantic (eq. 3, cosine of the two
   masks' embeddings) under ``appearance-hsv`` and under ``imagenet-minilm``; ROC AUC of
   same-object vs different-object pairs.
2. Calibration: tau_sem for the learned features is set at the same false-merge rate (share
   of different-object pairs with S_semantic >= tau) that appearance-hsv has at its
   tau_sem = 0.65, so stage 2 is equally permissive.
3. Check: AP / AP50 of the default pipeline with each embedder (generated scenes, the
   evaluation's metrics), and with ``--samples`` leaf-pair F1 against the original
   release's trees on the real samples (``segmentation/compare.py``).

The learned features are computed once per scene (a memo keyed by the image and mask bytes)
and reused for every tau. Not a unit test: numbers depend on the scenes drawn.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))


class Memo:
    """A mask embedder that computes each (image, masks) stack once."""

    def __init__(self, inner) -> None:
        self.inner, self.name, self.dim, self.cache = inner, inner.name, inner.dim, {}

    def embed_masks(self, rgb, masks):
        key = hashlib.sha1(rgb.tobytes() + np.packbits(masks).tobytes() + str(masks.shape).encode()).hexdigest()
        if key not in self.cache:
            self.cache[key] = self.inner.embed_masks(rgb, masks)
        return self.cache[key]


def auc(pos: np.ndarray, neg: np.ndarray) -> float:
    from scipy.stats import rankdata

    r = rankdata(np.concatenate([pos, neg]))
    return float((r[: len(pos)].sum() - len(pos) * (len(pos) + 1) / 2) / (len(pos) * len(neg)))


def leaf_pairs(seg, scene):
    """(i, j, same) for cross-view non-background leaf pairs with a clear GT object."""
    tr, gt = seg.trace, scene.ground_truth
    views = {v.frame: v for v in scene.initial_views}
    obj = np.full(len(tr.nodes), -2, np.int64)
    for i in np.flatnonzero(tr.nodes.is_leaf & ~tr.nodes.background):
        v = views[int(tr.nodes.frame[i])]
        m = v.masks.masks[v.masks.index_of(int(tr.nodes.mask_id[i]))]
        lab = gt.instance_maps[v.frame][m]
        if lab.size:
            vals, cnt = np.unique(lab, return_counts=True)
            if cnt.max() >= 0.8 * lab.size and vals[np.argmax(cnt)] >= 0:
                obj[i] = vals[np.argmax(cnt)]
    idx = np.flatnonzero(obj >= 0)
    out = []
    for a in range(len(idx)):
        for b in range(a + 1, len(idx)):
            i, j = idx[a], idx[b]
            if tr.nodes.view[i] != tr.nodes.view[j]:
                out.append((i, j, obj[i] == obj[j]))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=Path("/tmp/clutt3r-bench-query"))
    ap.add_argument("--presets", nargs="+", default=["easy", "intermediate", "hard"])
    ap.add_argument("--seeds", nargs="+", type=int, default=[10, 11])
    ap.add_argument("--samples", action="store_true")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()

    from bench_query import prepare

    from clutt3r_core.config import SegmentConfig
    from clutt3r_core.embeddings import create_embedder
    from clutt3r_core.evaluation.metrics import evaluate_instances
    from clutt3r_core.io import load_scene
    from clutt3r_core.pipeline import segment

    hsv = create_embedder("appearance-hsv")
    learned = Memo(create_embedder("imagenet-minilm"))
    scenes = []
    pos = {"hsv": [], "learned": []}
    neg = {"hsv": [], "learned": []}
    for preset in args.presets:
        for seed in args.seeds:
            scene_dir, _ = prepare(args.work, preset, seed)
            sc = load_scene(scene_dir)
            base = SegmentConfig()
            seg_h = segment(sc, base, embedder=hsv)
            seg_l = segment(sc, replace(base, embedder="imagenet-minilm"), embedder=learned)
            for i, j, same in leaf_pairs(seg_h, sc):
                for key, seg in (("hsv", seg_h), ("learned", seg_l)):
                    e = seg.trace.embeddings
                    (pos if same else neg)[key].append(float(e[i] @ e[j]))
            scenes.append((f"{preset}-{seed}", sc))
            print(f"{preset}-{seed}: {len(pos['hsv'])} same / {len(neg['hsv'])} different pairs so far", file=sys.stderr)
    rep: dict = {"scenes": [n for n, _ in scenes]}
    for key in ("hsv", "learned"):
        rep[f"auc_{key}"] = auc(np.array(pos[key]), np.array(neg[key]))
    tau_h = SegmentConfig().grouping.tau_sem
    fpr = float(np.mean(np.array(neg["hsv"]) >= tau_h))
    tau_l = float(np.quantile(np.array(neg["learned"]), 1.0 - fpr)) if fpr > 0 else float(np.max(neg["learned"]))
    tpr_h = float(np.mean(np.array(pos["hsv"]) >= tau_h))
    tpr_l = float(np.mean(np.array(pos["learned"]) >= tau_l))
    rep.update(tau_hsv=tau_h, false_merge_rate=fpr, tau_learned=round(tau_l, 3), tpr_hsv=tpr_h, tpr_learned=tpr_l)
    print(json.dumps(rep), file=sys.stderr)

    def cfg(emb: str, tau: float) -> SegmentConfig:
        c = SegmentConfig()
        return replace(c, embedder=emb, grouping=replace(c.grouping, tau_sem=tau))

    ap_rows = {}
    for label, emb, tau, obj in (("hsv", "appearance-hsv", tau_h, hsv),
                                 ("learned", "imagenet-minilm", round(tau_l, 3), learned)):
        aps, ap50s = [], []
        for name, sc in scenes:
            seg = segment(sc, cfg(emb, tau), embedder=obj)
            r, _ = evaluate_instances(seg.points, seg.instance, seg.scores, sc.ground_truth)
            aps.append(r.ap)
            ap50s.append(r.ap50)
        ap_rows[label] = {"tau_sem": tau, "AP": float(np.mean(aps)), "AP50": float(np.mean(ap50s)),  # APResult is in %
                          "per_scene_AP": [round(a, 1) for a in aps]}
        print(json.dumps({label: ap_rows[label]}), file=sys.stderr)
    rep["ap"] = ap_rows
    if args.samples:
        from clutt3r_core.pipeline import instance_tree_json
        from clutt3r_core.segmentation.compare import leaf_pair_agreement

        samples = ROOT.parent / "shared" / "data" / "clutt3r-samples"
        rep["samples"] = {}
        for seq in ("sample_seq1", "sample_seq4"):
            folder = samples / seq / "data"
            if not folder.is_dir():
                continue
            sc = load_scene(folder)
            row = {}
            for label, emb, tau, obj in (("hsv", "appearance-hsv", tau_h, hsv),
                                         ("learned", "imagenet-minilm", round(tau_l, 3), learned)):
                seg = segment(sc, cfg(emb, tau), embedder=obj)
                agr = leaf_pair_agreement(instance_tree_json(seg), folder / "instance_tree.json")
                row[label] = round(agr.f1, 3)
            rep["samples"][seq] = row
            print(json.dumps({seq: row}), file=sys.stderr)
    text = json.dumps(rep, indent=1)
    print(text)
    if args.out:
        args.out.write_text(text)


if __name__ == "__main__":
    main()
