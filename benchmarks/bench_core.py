"""Benchmark the segmentation core (segment(), mask generation excluded) and prove it unchanged.

Usage:
    .venv/bin/python benchmarks/bench_core.py [--per-preset 1] [--presets easy intermediate hard]
        [--runs 3] [--naive-runs 1] [--no-naive] [--samples sample_seq1 sample_seq4] [--out bench.json]

For every scene (N generated 8-view 640x480 scenes per preset, then the real samples
that are present) it reports the median over ``--runs`` warm runs of every stage of
``segment(scene).trace.timings``, the core total with and without the embedding stage,
the tracemalloc peak of one ``segment()`` call and the process max RSS.

Baselines, measured in the same process on the same scenes:

- ``naive``: the core as it was before the speed work (commit 0c7aa07): dense
  blockwise S_spatial, per-pixel (mask, pixel) gathers for hits / embeddings, mask
  overlaps through uint64 codes and a sort, SVD plane refinement, sorted voxel keys,
  hits computed twice per view. The old functions are kept below and patched in with
  ``unittest.mock``; each naive run is also an equality check: every output of the
  fast core (instances, scores, super-voxels, occupancy, S_spatial, embeddings, normals)
  must equal the naive one (floats to 1e-6; S_spatial to 3e-5, the round-off of the old
  float32 dense sums, which the new float64 sums do not have).
- ``paper``: the runtime the paper reports per scene with 8 views (Table I: 57.2 s on
  GraspClutter6D, 21.5 s on the synthetic set). That figure includes Grounded-SAM mask
  generation and Duoduo CLIP, so the ratio only says how small the core's share is.

Targets (this project, 2-core machine, embeddings excluded): <= 2 s per generated
640x480 scene, <= 6 s for sample_seq4 (1920x1080). Not a unit test: the numbers depend
on the machine and its load; the equality check does not.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import resource
import statistics
import sys
import time
import tracemalloc
from pathlib import Path
from unittest import mock

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from clutt3r_core.pipeline import Segmentation, segment  # noqa: E402

SAMPLES = ROOT.parent / "shared" / "data" / "clutt3r-samples"
PAPER_SECONDS = {"real": 57.2, "generated": 21.5}  # Table I, Clutt3R-Seg, 8 views
TARGET_SECONDS = {"generated": 2.0, "sample_seq4": 6.0, "sample_seq1": 2.0}
STAGES = ("pointcloud", "supervoxels", "trees", "occupancy", "embeddings", "leaf_graph", "grouping", "vote")


# --------------------------------------------------------------------------------------
# The pre-optimisation core (commit 0c7aa07), kept as the naive baseline.
# --------------------------------------------------------------------------------------

def _naive_spatial_similarity(occupancy, weights, eps=1e-9):
    occ = np.asarray(occupancy, np.float32)
    cols = np.flatnonzero(occ.max(axis=0, initial=0) > 0)
    occ = occ[:, cols]
    w = np.asarray(weights, np.float32)[cols]
    u = occ.shape[0]
    inter = np.zeros((u, u), np.float32)
    union = np.zeros((u, u), np.float32)
    block = max(1, int(2e7 // max(1, u * len(cols))))
    for s in range(0, u, block):
        a = occ[s : s + block, None, :]
        inter[s : s + block] = (np.minimum(a, occ[None]) * w).sum(-1)
        union[s : s + block] = (np.maximum(a, occ[None]) * w).sum(-1)
    return inter / (union + eps)


def _stack(masks):
    """The (M, H, W) bool stack the pre-optimisation code read (the core now passes the compact
    ``MaskCandidates``; building the stack is part of what the naive core cost)."""
    from clutt3r_core.scene import MaskCandidates

    return masks.masks if isinstance(masks, MaskCandidates) else masks


def _naive_csr_hits(cloud, view_index, masks):
    from clutt3r_core.occupancy import _check_masks, _view_pixels

    masks = _check_masks(cloud, view_index, _stack(masks))
    pix, vox = _view_pixels(cloud, view_index)
    m = masks.shape[0]
    sub = masks.reshape(m, masks.shape[1] * masks.shape[2])[:, pix]
    rows, cols = np.nonzero(sub)
    hits = sp.coo_matrix(
        (np.ones(len(rows), np.float32), (rows, vox[cols])), shape=(m, cloud.num), dtype=np.float32
    ).tocsr()
    hits.sum_duplicates()
    return hits


def _naive_mask_voxel_hits(cloud, view_index, masks):
    """The scipy CSR of the old code, handed on as the ``VoxelHits`` the core now takes (the
    same canonical entries)."""
    from clutt3r_core.occupancy import VoxelHits

    h = _naive_csr_hits(cloud, view_index, masks)
    row = np.repeat(np.arange(h.shape[0], dtype=np.int64), np.diff(h.indptr))
    return VoxelHits(row, h.indices.astype(np.int64), h.data.astype(np.float32), h.shape)


def _naive_mask_occupancy(cloud, sv, view_index, masks, cfg, hits=None):
    from clutt3r_core.occupancy import _view_pixels

    hits = _naive_csr_hits(cloud, view_index, masks)  # recomputed, as before
    n, k = cloud.num, sv.num
    _, vox = _view_pixels(cloud, view_index)
    fed = np.bincount(vox, minlength=n).astype(np.float64)
    c = cloud.counts.astype(np.float64)
    scale = np.divide(c, fed, out=np.zeros(n), where=fed > 0)
    member = sp.csr_matrix((scale, (np.arange(n), sv.labels)), shape=(n, k))
    num = np.asarray((hits.astype(np.float64) @ member).todense())
    if cfg.normalise == "visible":
        den = np.bincount(sv.labels, weights=c * (fed > 0), minlength=k)
    else:
        den = np.bincount(sv.labels, weights=c, minlength=k)
    occ = np.divide(num, den[None, :], out=np.zeros_like(num), where=den[None, :] > 0)
    return np.clip(occ, 0.0, 1.0).astype(np.float32)


def _naive_mask_overlaps(masks):
    masks = _stack(masks)
    m = masks.shape[0]
    if m == 0:
        return np.zeros((0, 0), np.int64)
    flat = masks.reshape(m, -1)
    if m <= 63:
        codes = np.zeros(flat.shape[1], np.uint64)
        for b in range(m):
            codes |= flat[b].astype(np.uint64) << np.uint64(b)
        uniq, counts = np.unique(codes[codes != 0], return_counts=True)
        bits = ((uniq[:, None] >> np.arange(m, dtype=np.uint64)[None, :]) & np.uint64(1)).astype(np.int64)
        return bits.T @ (bits * counts[:, None])
    f = flat.astype(np.float32)
    return np.rint(f @ f.T).astype(np.int64)


def _naive_embed_masks(self, rgb, masks):
    import cv2

    masks = _stack(masks)
    m = masks.shape[0]
    out = np.zeros((m, self.dim), np.float32)
    if m == 0:
        return out
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2HSV_FULL).reshape(-1, 3).astype(np.int64)
    h, s, v = hsv[:, 0], hsv[:, 1], hsv[:, 2]
    hb = np.where(s >= self.min_saturation, h * self.hue_bins // 256, self.hue_bins)
    joint = hb * self.sat_bins + s * self.sat_bins // 256
    vb = (self.hue_bins + 1) * self.sat_bins + v * self.val_bins // 256
    mi, pix = np.nonzero(masks.reshape(m, -1))
    d = self.dim
    hist = np.bincount(mi * d + joint[pix], minlength=m * d).astype(np.float64)
    hist += np.bincount(mi * d + vb[pix], minlength=m * d)
    hist = np.sqrt(hist.reshape(m, d))
    norm = np.linalg.norm(hist, axis=1, keepdims=True)
    np.divide(hist, norm, out=hist, where=norm > 0)
    return hist.astype(np.float32)


def _naive_fit_plane_ransac(points, distance, iterations=500, seed=0, max_eval=4000, normals=None, min_normal_dot=0.0):
    # the same hypotheses as today's (support.ransac_hypothesis); the naive part is the
    # refinement by a full SVD of the (P, 3) inliers, as before the 3x3 scatter's eigh
    from clutt3r_core.support import ransac_hypothesis, refine_plane

    pts = np.asarray(points, dtype=np.float64)
    nr = np.asarray(normals, dtype=np.float64) if normals is not None and min_normal_dot > 0 else None
    plane = ransac_hypothesis(pts, distance, iterations, seed, max_eval, nr, min_normal_dot)
    if plane is None:
        return None
    return refine_plane(pts, nr, plane, distance, min_normal_dot,
                        normal_of=lambda q: np.linalg.svd(q, full_matrices=False)[2][2])


def _naive_group_keys(keys, ext):
    lin = keys[0] + ext[0] * (keys[1] + ext[1] * keys[2])
    ncells = int(np.prod(ext))
    if ncells <= 1 << 24:
        cnt = np.bincount(lin, minlength=ncells)
        occupied = np.flatnonzero(cnt)
        lut = np.empty(ncells, dtype=np.int64)
        lut[occupied] = np.arange(len(occupied))
        return lut[lin], cnt[occupied]
    _, inverse, counts = np.unique(lin, return_inverse=True, return_counts=True)
    return inverse.reshape(-1), counts


def _naive_node_table(views, trees):
    from clutt3r_core.pipeline import NodeTable

    frame, view, mask_id, parent, is_leaf, stacks = [], [], [], [], [], []
    offset = 0
    for vi, (v, t) in enumerate(zip(views, trees)):
        m = len(t.mask_ids)
        idx = np.array([v.masks.index_of(int(i)) for i in t.mask_ids], np.int64)
        stacks.append(v.masks.masks[idx] if m else np.zeros((0, *v.masks.shape), bool))  # always a copy
        frame.append(np.full(m, v.frame, np.int32))
        view.append(np.full(m, vi, np.int32))
        mask_id.append(t.mask_ids.astype(np.int32))
        parent.append(np.where(t.parent >= 0, t.parent + offset, -1).astype(np.int32))
        is_leaf.append(t.is_leaf)
        offset += m
    cat = lambda xs, dt: np.concatenate(xs).astype(dt) if xs else np.zeros(0, dt)  # noqa: E731
    return stacks, NodeTable(
        frame=cat(frame, np.int32), view=cat(view, np.int32), mask_id=cat(mask_id, np.int32),
        parent=cat(parent, np.int32), is_leaf=cat(is_leaf, bool), background=np.zeros(offset, bool),
    )


@contextlib.contextmanager
def naive_core():
    """Patch the pre-optimisation implementations into the core."""
    from clutt3r_core.embeddings import AppearanceEmbedder

    patches = [
        mock.patch("clutt3r_core.pipeline.spatial_similarity", _naive_spatial_similarity),
        mock.patch("clutt3r_core.pipeline.mask_voxel_hits", _naive_mask_voxel_hits),
        mock.patch("clutt3r_core.pipeline.mask_occupancy", _naive_mask_occupancy),
        mock.patch("clutt3r_core.pipeline._node_table", _naive_node_table),
        mock.patch("clutt3r_core.segmentation.trees.mask_overlaps", _naive_mask_overlaps),
        mock.patch.object(AppearanceEmbedder, "embed_masks", _naive_embed_masks),
        mock.patch("clutt3r_core.support.fit_plane_ransac", _naive_fit_plane_ransac),
        mock.patch("clutt3r_core.pointcloud._group_keys", _naive_group_keys),
    ]
    with contextlib.ExitStack() as stack:
        for p in patches:
            stack.enter_context(p)
        yield


# --------------------------------------------------------------------------------------


def _outputs(seg: Segmentation) -> dict[str, np.ndarray]:
    t = seg.trace
    return {
        "instance": seg.instance, "scores": seg.scores, "sv_labels": seg.sv_labels, "sv_support": seg.sv_support,
        "points": seg.points, "normals": seg.normals, "occupancy": t.occupancy, "s_spatial": t.s_spatial,
        "s_semantic": t.s_semantic, "embeddings": t.embeddings, "parent": t.nodes.parent,
        "background": t.nodes.background,
    }


def compare(a: Segmentation, b: Segmentation) -> tuple[bool, dict[str, float]]:
    """(all equal, max abs difference per float output)."""
    oa, ob = _outputs(a), _outputs(b)
    ok, diffs = True, {}
    for k in oa:
        x, y = np.asarray(oa[k]), np.asarray(ob[k])
        if x.shape != y.shape:
            ok = False
            diffs[k] = float("inf")
            continue
        if x.dtype.kind == "f":
            tol = 3e-5 if k == "s_spatial" else 1e-6
            d = float(np.nanmax(np.abs(x.astype(np.float64) - y))) if x.size else 0.0
            same_nan = np.array_equal(np.isnan(x), np.isnan(y))
            diffs[k] = d
            ok &= same_nan and d <= tol
        else:
            ok &= bool(np.array_equal(x, y))
    return ok, diffs


def _stage_times(seg: Segmentation) -> dict[str, float]:
    out = {s: 0.0 for s in STAGES}
    for t in seg.trace.timings:
        out[t.stage] = out.get(t.stage, 0.0) + t.seconds
    return out


def _median_times(runs: list[dict[str, float]]) -> dict[str, float]:
    stages = {k: statistics.median(r[k] for r in runs) for k in runs[0]}
    totals = [sum(r.values()) for r in runs]
    no_emb = [sum(v for k, v in r.items() if k != "embeddings") for r in runs]
    return {"stages": stages, "total": statistics.median(totals), "total_no_embeddings": statistics.median(no_emb)}


def bench_scene(name: str, kind: str, scene, runs: int, naive_runs: int) -> dict:
    segment(scene)  # warm: imports, first-touch allocations
    fast_runs, fast, cpu = [], None, []
    for _ in range(runs):
        c0 = time.process_time()
        fast = segment(scene)
        cpu.append(time.process_time() - c0)
        fast_runs.append(_stage_times(fast))
    tracemalloc.start()
    segment(scene)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    res = {
        "scene": name, "kind": kind, "views": len(scene.initial_views),
        "image": list(scene.initial_views[0].depth.shape), "voxels": int(len(fast.points)),
        "supervoxels": int(len(fast.sv_support)), "nodes": int(len(fast.trace.nodes)),
        "fast": _median_times(fast_runs), "tracemalloc_peak_mb": peak / 2**20,
        # CPU seconds of the whole segment() call (all threads): less sensitive than wall
        # time to other processes on the machine, more than wall time where threads help.
        "fast_cpu_seconds": statistics.median(cpu), "load_average": list(__import__("os").getloadavg()),
    }
    if naive_runs:
        naive_list, naive = [], None
        with naive_core():
            for _ in range(naive_runs):
                naive = segment(scene)
                naive_list.append(_stage_times(naive))
        equal, diffs = compare(fast, naive)
        res["naive"] = _median_times(naive_list)
        res["equal_to_naive"] = equal
        res["max_abs_diff"] = diffs
        res["speedup_vs_naive"] = res["naive"]["total_no_embeddings"] / res["fast"]["total_no_embeddings"]
    res["paper_seconds"] = PAPER_SECONDS["generated" if kind == "generated" else "real"]
    res["paper_ratio"] = res["paper_seconds"] / res["fast"]["total"]
    target = TARGET_SECONDS.get(name, TARGET_SECONDS["generated"] if kind == "generated" else None)
    res["target_seconds"] = target
    res["meets_target"] = None if target is None else res["fast"]["total_no_embeddings"] <= target
    res["max_rss_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    return res


def _scenes(args):
    from clutt3r_core.synth import SynthConfig, generate_scene

    for preset in args.presets:
        for seed in range(args.per_preset):
            t = time.perf_counter()
            sc = generate_scene(SynthConfig(seed=seed, preset=preset), progress=False)
            print(f"generated {preset} seed {seed} in {time.perf_counter() - t:.1f} s", file=sys.stderr)
            yield f"gen-{preset}-{seed}", "generated", sc
    for name in args.samples:
        folder = SAMPLES / name / "data"
        if not folder.is_dir():
            print(f"skip {name}: {folder} not found", file=sys.stderr)
            continue
        from clutt3r_core.io import load_scene

        yield name, "real", load_scene(folder)


def markdown(results: list[dict]) -> str:
    hdr = ["scene", *STAGES, "core", "core w/o emb", "CPU s", "naive w/o emb", "speed-up", "equal", "peak MB", "target"]
    lines = ["| " + " | ".join(hdr) + " |", "|" + "---|" * len(hdr)]
    for r in results:
        f = r["fast"]
        row = [r["scene"], *(f"{f['stages'][s]:.3f}" for s in STAGES), f"{f['total']:.2f}", f"{f['total_no_embeddings']:.2f}",
               f"{r['fast_cpu_seconds']:.2f}"]
        if "naive" in r:
            row += [f"{r['naive']['total_no_embeddings']:.2f}", f"{r['speedup_vs_naive']:.1f}x", "yes" if r["equal_to_naive"] else "NO"]
        else:
            row += ["-", "-", "-"]
        row.append(f"{r['tracemalloc_peak_mb']:.0f}")
        row.append("-" if r["target_seconds"] is None else f"{'ok' if r['meets_target'] else 'MISSED'} (<= {r['target_seconds']:g} s)")
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-preset", type=int, default=1, help="generated scenes per preset (seeds 0..N-1)")
    ap.add_argument("--presets", nargs="*", default=["easy", "intermediate", "hard"])
    ap.add_argument("--samples", nargs="*", default=["sample_seq1", "sample_seq4"])
    ap.add_argument("--runs", type=int, default=3, help="timed runs per scene (median)")
    ap.add_argument("--naive-runs", type=int, default=1, help="runs of the pre-optimisation core (0 = skip)")
    ap.add_argument("--no-naive", action="store_true", help="same as --naive-runs 0")
    ap.add_argument("--out", type=Path, default=None, help="write all numbers as JSON here")
    args = ap.parse_args(argv)
    naive_runs = 0 if args.no_naive else args.naive_runs

    results = []
    for name, kind, sc in _scenes(args):
        r = bench_scene(name, kind, sc, args.runs, naive_runs)
        results.append(r)
        eq = "" if "naive" not in r else f", naive {r['naive']['total_no_embeddings']:.2f} s, equal={r['equal_to_naive']}"
        print(f"{name}: core {r['fast']['total']:.2f} s, w/o embeddings {r['fast']['total_no_embeddings']:.2f} s{eq}",
              file=sys.stderr)
    table = markdown(results)
    print(table)
    gen = [r["fast"]["total_no_embeddings"] for r in results if r["kind"] == "generated"]
    summary = {
        "generated_median_no_embeddings": statistics.median(gen) if gen else None,
        "generated_max_no_embeddings": max(gen) if gen else None,
        "all_equal_to_naive": all(r.get("equal_to_naive", True) for r in results),
        "all_targets_met": all(r["meets_target"] in (None, True) for r in results),
        "max_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
    }
    print()
    print(f"generated scenes, core w/o embeddings: median {summary['generated_median_no_embeddings']}, "
          f"max {summary['generated_max_no_embeddings']} s; process max RSS {summary['max_rss_mb']:.0f} MB; "
          f"paper per scene {PAPER_SECONDS['real']} s (real) / {PAPER_SECONDS['generated']} s (synthetic), incl. masks + CLIP")
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"summary": summary, "scenes": results}, indent=1))
    return 0 if summary["all_equal_to_naive"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
