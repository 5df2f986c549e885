"""Benchmark report: Markdown tables in the paper's layout, results JSON and PNG plots.

Numbers are means over scenes of per-scene AP (percent); the pooled, ScanNet
dataset-level AP (one ranking over all scenes of a split) is reported beside them.
Times are seconds per scene (sum of the method's stages, as the pipeline's trace
reports them); memory is MiB.
"""

from __future__ import annotations

import json
import math
import os
import platform
from collections import defaultdict
from pathlib import Path
from typing import Sequence

import numpy as np

from clutt3r_core.evaluation.report_breakdown import breakdown_section, depth_section
from clutt3r_core.io.images import atomic_write_bytes

__all__ = ["write_report", "summary_rows", "ablation_tables"]

_NAMES = {
    "ours": "Clutt3R (ours, default)",
    "paper": "Clutt3R, paper's text (additions off)",
    "no-spatial": "w/o S_spatial",
    "no-substitution": "w/o substitution",
    "ours-noisy-depth": "Clutt3R, noisy-depth preset",
    "naive": "Naive 3D-IoU merging",
    "maskclustering": "MaskClustering (re-impl.)",
}
_ORDER = ("naive", "maskclustering", "paper", "no-spatial", "no-substitution", "ours", "ours-noisy-depth")
_DIFF = ("easy", "intermediate", "hard")


def _mean(xs) -> float:
    xs = [x for x in xs if x is not None and not (isinstance(x, float) and math.isnan(x))]
    return float(np.mean(xs)) if xs else float("nan")


def _f(x: float, nd: int = 1) -> str:
    return "–" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{nd}f}"


def _is_ablation(m: str) -> bool:
    return m.startswith("ours-no-") or m.startswith("paper-with-")


def _methods(results) -> list[str]:
    """Methods of the main tables, in the report's order (the leave-one-out ablation has its own)."""
    present = {r.method for r in results if not _is_ablation(r.method)}
    return [m for m in _ORDER if m in present] + sorted(present - set(_ORDER))


def ablation_tables(results, agreement: dict[str, dict[str, float]] | None = None) -> str:
    """Markdown: the leave-one-out ablation of our additions (``config.ADDITIONS``).

    ``results``: JobResults of ``ours``, ``paper`` and the ``ours-no-*`` / ``paper-with-*``
    methods (main setting). One row per addition: ours with it off and the paper preset with
    it on, mean AP over the scenes, and the change against ours / paper. ``agreement``:
    optional method -> {sample name: leaf-pair F1} on real sequences (``segmentation.compare``).
    Empty string when there are no ablation results.
    """
    from clutt3r_core.config import ADDITIONS

    summ = summary_rows(results, key=lambda r: "all")
    if not any(_is_ablation(m) for m, _ in summ):
        return ""
    samples = sorted({k for v in (agreement or {}).values() for k in v})

    def cells(m: str, ref: str) -> list[str]:
        a, b = summ.get((m, "all")), summ.get((ref, "all"))
        if a is None:
            return ["–"] * (5 + len(samples))
        d = (lambda k: _f(a[k] - b[k]) if b else "–")
        out = [_f(a["ap25"]), _f(a["ap50"]), _f(a["ap"]), d("ap50"), d("ap")]
        return out + [_f((agreement or {}).get(m, {}).get(sm, float("nan")), 3) for sm in samples]

    head = ["AP25", "AP50", "AP", "ΔAP50", "ΔAP"] + [f"{sm} F1" for sm in samples]
    rows_o = [["**ours** (all on)", ""] + cells("ours", "ours")]
    rows_p = [["**paper** (all off)", ""] + cells("paper", "paper")]
    for a in ADDITIONS:
        what = a.what.replace("|", "\\|")  # a cell of a Markdown table
        rows_o.append([f"`{a.key}` off", what] + cells(f"ours-no-{a.key}", "ours"))
        needs = f" (with {', '.join(f'`{n}`' for n in a.needs)})" if a.needs else ""
        rows_p.append([f"`{a.key}` on{needs}", what] + cells(f"paper-with-{a.key}", "paper"))
    scenes = sorted({r.scene for r in results if _is_ablation(r.method)})
    md = [f"Scenes ({len(scenes)}): " + ", ".join(f"`{x}`" for x in scenes) + ". Mean over scenes of per-scene AP; "
          "Δ is against ours (first table) or the paper preset (second). "
          + ("F1: leaf-pair agreement with the original method's instance_tree.json on the real samples "
             "(`clutt3r_core/segmentation/compare.py`). " if samples else "")
          + "Each addition's switch and the paper's value: `clutt3r_core/config.py` `ADDITIONS`; the choices "
          "the paper leaves open: docs/paper_choices.md.", "",
          "**Ours with one addition switched off** (leave-one-out):", "",
          _table(["addition", "what it does"] + head, rows_o), "",
          "**The paper preset with one addition switched on:**", "",
          _table(["addition", "what it does"] + head, rows_p), ""]
    return "\n".join(md)


def summary_rows(results, key=lambda r: r.difficulty) -> dict[tuple[str, str], dict[str, float]]:
    """(method, group) -> mean ap25/ap50/ap/seconds/n over the results of that group."""
    acc: dict[tuple[str, str], list] = defaultdict(list)
    for r in results:
        acc[(r.method, key(r))].append(r)
    return {
        k: {"ap25": _mean(x.ap25 for x in v), "ap50": _mean(x.ap50 for x in v), "ap": _mean(x.ap for x in v),
            "seconds": _mean(x.seconds for x in v), "n": len(v)}
        for k, v in acc.items()
    }


def _pooled(results) -> tuple[float, float, float]:
    from clutt3r_core.evaluation.metrics import pooled_ap

    if not results:
        return (float("nan"),) * 3
    p = pooled_ap([r.matches() for r in results])
    return p.ap25, p.ap50, p.ap


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def _bold_best(rows: list[list[str]], cols: Sequence[int], higher: bool = True) -> None:
    for c in cols:
        vals = []
        for r in rows:
            try:
                vals.append(float(r[c].strip("*")))
            except ValueError:
                vals.append(float("nan"))
        ok = [v for v in vals if not math.isnan(v)]
        if not ok:
            continue
        best = max(ok) if higher else min(ok)
        for r, v in zip(rows, vals):
            if v == best:
                r[c] = f"**{r[c]}**"


def _occlusion_split(results) -> tuple[dict[str, str], list[tuple[str, float]]]:
    """Scene -> tertile label by mean occlusion (paper Sec. IV-A split); labels with their mean occlusion."""
    occ = {}
    for r in results:
        if not math.isnan(r.mean_occlusion):
            occ[r.scene] = r.mean_occlusion
    if len(occ) < 3:
        return {}, []
    names = sorted(occ, key=lambda s: (occ[s], s))
    parts = np.array_split(np.arange(len(names)), 3)
    labels = ("low occlusion", "mid occlusion", "high occlusion")
    out, means = {}, []
    for lab, idx in zip(labels, parts):
        for i in idx:
            out[names[i]] = lab
        means.append((lab, float(np.mean([occ[names[i]] for i in idx]))))
    return out, means


def _plots(out: Path, main_res, view_res, noise_res, methods: list[str]) -> list[str]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    files = []
    colors = {m: c for m, c in zip(_ORDER, ("#999999", "#e69f00", "#56b4e9", "#cc79a7", "#009e73", "#d55e00"))}
    summ = summary_rows(main_res)
    diffs = [d for d in _DIFF if any((m, d) in summ for m in methods)]
    if diffs:
        fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
        for ax, metric, title in zip(axes, ("ap25", "ap50", "ap"), ("AP@25", "AP@50", "AP (50:95)")):
            for m in methods:
                ys = [summ.get((m, d), {}).get(metric, np.nan) for d in diffs]
                ax.plot(diffs, ys, "o--" if m == "no-substitution" else "o-", label=_NAMES.get(m, m),
                        color=colors.get(m), lw=2.5 if m == "ours" else 1.5, zorder=3 if m == "no-substitution" else 2)
            ax.set_title(title)
            ax.set_ylim(0, 100)
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("AP (%)")
        axes[-1].legend(fontsize=8, loc="lower left")
        fig.suptitle("AP vs difficulty (mean over scenes, 8 views, grounded-sam-like masks)")
        fig.tight_layout()
        fig.savefig(out / "ap_vs_difficulty.png", dpi=110)
        plt.close(fig)
        files.append("ap_vs_difficulty.png")
    if view_res:
        vs = summary_rows(view_res, key=lambda r: str(r.views))
        views = sorted({r.views for r in view_res})
        vm = [m for m in methods if any((m, str(v)) in vs for v in views)]
        fig, axes = plt.subplots(1, 3, figsize=(13, 4), sharey=True)
        for ax, metric, title in zip(axes, ("ap25", "ap50", "ap"), ("AP@25", "AP@50", "AP (50:95)")):
            for m in vm:
                ax.plot(views, [vs.get((m, str(v)), {}).get(metric, np.nan) for v in views], "o-",
                        label=_NAMES.get(m, m), color=colors.get(m), lw=2.5 if m == "ours" else 1.5)
            ax.set_title(title)
            ax.set_xticks(views)
            ax.set_xlabel("views")
            ax.set_ylim(0, 100)
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("AP (%)")
        axes[-1].legend(fontsize=8, loc="lower right")
        fig.suptitle("AP vs number of views (sweep subset)")
        fig.tight_layout()
        fig.savefig(out / "ap_vs_views.png", dpi=110)
        plt.close(fig)
        files.append("ap_vs_views.png")
    if noise_res:
        ns = summary_rows(noise_res, key=lambda r: r.mask_noise)
        noises = [n for n in ("clean", "grounded-sam-like", "harsh") if any(r.mask_noise == n for r in noise_res)]
        nm = [m for m in methods if any((m, n) in ns for n in noises)]
        fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
        for ax, metric, title in zip(axes, ("ap25", "ap50"), ("AP@25", "AP@50")):
            for m in nm:
                ax.plot(noises, [ns.get((m, n), {}).get(metric, np.nan) for n in noises], "o-",
                        label=_NAMES.get(m, m), color=colors.get(m), lw=2.5 if m == "ours" else 1.5)
            ax.set_title(title)
            ax.set_ylim(0, 100)
            ax.grid(alpha=0.3)
        axes[0].set_ylabel("AP (%)")
        axes[-1].legend(fontsize=8)
        fig.suptitle("AP vs mask-candidate noise (sweep subset, 8 views)")
        fig.tight_layout()
        fig.savefig(out / "ap_vs_noise.png", dpi=110)
        plt.close(fig)
        files.append("ap_vs_noise.png")
    # stacked per-stage time
    stages: list[str] = []
    for r in main_res:
        for s, _ in r.stages:
            if s not in stages:
                stages.append(s)
    if stages and main_res:
        fig, ax = plt.subplots(figsize=(10, 4.5))
        cmap = plt.get_cmap("tab20")
        bottom = np.zeros(len(methods))
        for si, s in enumerate(stages):
            vals = np.array([_mean(dict(r.stages).get(s, 0.0) for r in main_res if r.method == m) for m in methods])
            vals = np.nan_to_num(vals)
            ax.bar([_NAMES.get(m, m) for m in methods], vals, bottom=bottom, label=s, color=cmap(si))
            bottom += vals
        ax.set_ylabel("seconds per scene (mean)")
        ax.set_title("Time per stage (8 views, 640x480 unless stated; 1 thread per worker)")
        ax.legend(fontsize=8, ncol=2)
        plt.setp(ax.get_xticklabels(), rotation=15, ha="right", fontsize=8)
        fig.tight_layout()
        fig.savefig(out / "time_per_stage.png", dpi=110)
        plt.close(fig)
        files.append("time_per_stage.png")
    return files


def write_report(
    results,
    out: str | Path,
    command: str = "",
    elapsed: float = float("nan"),
    workers: int = 1,
    main=None,
    markdown: str | Path | None = None,
    notes: str = "",
) -> Path:
    """Write ``out/report.md``, ``out/results.json`` and the plots; returns the report path.

    ``main``: the main ``Setting`` (8 views, grounded-sam-like); results of other settings
    feed the sweeps. ``markdown``: where to write the Markdown (default ``out/report.md``);
    plot links are relative to it.
    """
    from clutt3r_core.evaluation.jobs import Setting, code_version

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    main = main or Setting()
    # results of the other depth model (issue 13's sweep) have a table of their own
    depth_res = [r for r in results if r.depth_noise not in (main.depth_noise, "scene")]
    all_results, results = results, [r for r in results if r.depth_noise in (main.depth_noise, "scene")]
    res_all_main = [r for r in results if r.views == main.views and r.mask_noise == main.mask_noise]
    res_main = [r for r in res_all_main if not _is_ablation(r.method)]
    methods = _methods(res_main)
    main_scene_names = {r.scene for r in res_main}
    sweep_scenes = {r.scene for r in results if (r.views, r.mask_noise) != (main.views, main.mask_noise)}
    view_res = [r for r in results if r.mask_noise == main.mask_noise and r.scene in sweep_scenes]
    noise_res = [r for r in results if r.views == main.views and r.scene in sweep_scenes
                 and r.method in {x.method for x in results if x.mask_noise != main.mask_noise}]
    swept = {r.method for r in view_res if r.views != main.views}
    view_res = [r for r in view_res if r.method in swept]  # methods run at one view count only are in Table I
    if not {r.views for r in view_res} - {main.views}:
        view_res = []
    if not {r.mask_noise for r in noise_res} - {main.mask_noise}:
        noise_res = []
    plots = _plots(out, res_main, view_res, noise_res, methods)
    report = Path(markdown) if markdown is not None else out / "report.md"
    rel = os.path.relpath(out.resolve(), report.resolve().parent)
    pd = "" if rel == "." else rel.rstrip("/") + "/"

    md: list[str] = ["# Clutt3R benchmark", ""]
    ndiff = defaultdict(set)
    for r in res_main:
        ndiff[r.difficulty].add(r.scene)
    md += [
        f"Scenes: {len(main_scene_names)} ("
        + ", ".join(f"{len(ndiff[d])} {d}" for d in list(_DIFF) + sorted(set(ndiff) - set(_DIFF)) if ndiff[d])
        + f"); main setting {main.views} views, `{main.mask_noise if main.masks == 'scene' else main.masks}` mask candidates, "
        f"`{main.depth_noise}` depth (generated scenes). "
        f"Jobs: {len(all_results)} ({sum(r.cached for r in all_results)} from cache). "
        f"Wall time of this run: {_f(elapsed / 60, 1)} min with {workers} worker(s) on "
        f"{os.cpu_count()} CPU(s) ({platform.processor() or platform.machine()}). Code version of the results: "
        + ", ".join(f"`{v}`" for v in sorted({r.code_version for r in results} - {""})) + ".",
        "",
    ]
    if command:
        md += ["Reproduce:", "", "```", command, "```", ""]
    md += [
        "AP is class-agnostic 3D instance AP on a 10 mm grid (paper Sec. IV-A; ScanNet protocol, "
        "see `clutt3r_core/evaluation/metrics.py`), mean over scenes of per-scene AP, in percent. "
        "Time is seconds per scene summed over the method's stages (fusion to instances; "
        "scene generation and evaluation excluded), one thread per worker. "
        "All methods get the same fused cloud and the same mask candidates; the baselines also get our "
        "support (table / tray) flags and background-mask rule, so only the grouping differs "
        "(`clutt3r_core/baselines/`). MaskClustering is our re-implementation from its paper's "
        "description, not the authors' code.",
        "",
    ]

    # Table I
    summ = summary_rows(res_main)
    summ_all = summary_rows(res_main, key=lambda r: "all")
    diffs = [d for d in list(_DIFF) + sorted({r.difficulty for r in res_main} - set(_DIFF)) if ndiff[d]]
    header = ["Method"] + [f"{d} {m}" for d in diffs for m in ("AP25", "AP50", "AP")] + ["all AP25", "all AP50", "all AP", "Time (s)"]
    rows = []
    for m in methods:
        row = [_NAMES.get(m, m)]
        for d in diffs:
            s = summ.get((m, d), {})
            row += [_f(s.get("ap25", np.nan)), _f(s.get("ap50", np.nan)), _f(s.get("ap", np.nan))]
        a = summ_all.get((m, "all"), {})
        row += [_f(a.get("ap25", np.nan)), _f(a.get("ap50", np.nan)), _f(a.get("ap", np.nan)), _f(a.get("seconds", np.nan), 2)]
        rows.append(row)
    _bold_best(rows, range(1, len(header) - 1))
    _bold_best(rows, [len(header) - 1], higher=False)
    md += ["## Table I: class-agnostic 3D instance segmentation by difficulty", "", _table(header, rows), ""]
    if "ap_vs_difficulty.png" in plots:
        md += [f"![AP vs difficulty]({pd}ap_vs_difficulty.png)", ""]

    # who wins
    base = [b for b in ("naive", "maskclustering") if b in methods]
    if "ours" in methods and base:
        losses = []
        for d in diffs:
            for metric in ("ap25", "ap50", "ap"):
                o = summ.get(("ours", d), {}).get(metric, np.nan)
                for b in base:
                    v = summ.get((b, d), {}).get(metric, np.nan)
                    if not (o > v):
                        losses.append(f"{d} {metric.upper()}: ours {_f(o)} vs {_NAMES[b]} {_f(v)}")
        md += ["**Ours vs baselines:** " + ("ours is ahead of both baselines on every difficulty and metric." if not losses
               else "ours is not ahead in: " + "; ".join(losses) + "."), ""]

    # pooled
    rows = []
    for m in methods:
        row = [_NAMES.get(m, m)]
        for d in diffs:
            row += [_f(x) for x in _pooled([r for r in res_main if r.method == m and r.difficulty == d])]
        rows.append(row)
    _bold_best(rows, range(1, 1 + 3 * len(diffs)))
    md += ["### Table I (pooled): ScanNet dataset-level AP, one ranking over all scenes of a difficulty", "",
           _table(["Method"] + [f"{d} {m}" for d in diffs for m in ("AP25", "AP50", "AP")], rows), ""]

    # occlusion split
    split, means = _occlusion_split(res_main)
    if split:
        so = summary_rows([r for r in res_main if r.scene in split], key=lambda r: split[r.scene])
        header = ["Method"] + [f"{lab} ({100 * mo:.0f}%) {m}" for lab, mo in means for m in ("AP25", "AP50", "AP")]
        rows = []
        for m in methods:
            row = [_NAMES.get(m, m)]
            for lab, _ in means:
                s = so.get((m, lab), {})
                row += [_f(s.get("ap25", np.nan)), _f(s.get("ap50", np.nan)), _f(s.get("ap", np.nan))]
            rows.append(row)
        _bold_best(rows, range(1, len(header)))
        md += ["## Table I by occlusion (paper-style split)", "",
               "The paper splits its sequences into three equal parts by mean occlusion. Here all scenes of the "
               "main setting are sorted by the generator's mean occlusion (fraction of each object's silhouette "
               "hidden by others, averaged over objects and views) and cut into thirds; the percentage is the mean "
               "occlusion of each third.", "", _table(header, rows), ""]

    # Table III ablation
    abl = [m for m in ("paper", "no-spatial", "no-substitution", "ours") if m in methods]
    if len(abl) > 1:
        rows = []
        for m in abl:
            a = summ_all.get((m, "all"), {})
            row = [_NAMES.get(m, m), _f(a["ap25"]), _f(a["ap50"]), _f(a["ap"]), _f(a["seconds"], 2)]
            for d in diffs:
                row.append(_f(summ.get((m, d), {}).get("ap50", np.nan)))
            rows.append(row)
        _bold_best(rows, [1, 2, 3] + list(range(5, 5 + len(diffs))))
        _bold_best(rows, [4], higher=False)
        md += ["## Table III: ablation (all scenes)", "",
               "`paper` = the paper's text wherever it is explicit: every rule of ours (`config.ADDITIONS`: "
               "support marking, background masks, one mask per view, visible occupancy, overlap gate, coverage "
               "guard, |<n_i, n_j>|, 0.85 containment, minimum mask area and instance size, pixel stride) off; "
               "the choices the text leaves open are shared with ours (docs/paper_choices.md); `w/o S_spatial` skips stage 1; "
               "`w/o substitution` skips residual-node parent substitution.", "",
               _table(["Method", "AP25", "AP50", "AP", "Time (s)"] + [f"{d} AP50" for d in diffs], rows), ""]

    ablation = ablation_tables(res_all_main)
    if ablation:
        md += ["## Leave-one-out ablation of our additions over the paper", "", ablation]

    # Table IV view sweep
    if view_res:
        vs = summary_rows(view_res, key=lambda r: str(r.views))
        views = sorted({r.views for r in view_res})
        rows = []
        for m in methods:
            for v in views:
                s = vs.get((m, str(v)))
                if s:
                    rows.append([f"{_NAMES.get(m, m)} ({v} views)", _f(s["ap25"]), _f(s["ap50"]), _f(s["ap"]), _f(s["seconds"], 2)])
        _bold_best(rows, [1, 2, 3])
        nsc = len({r.scene for r in view_res})
        md += ["## Table IV: number of views", "",
               f"On the sweep subset ({nsc} scenes: the first of each difficulty), views chosen evenly from the 8 "
               "in frame order (the cameras lie on an arc, so the subset still spans it). The ground truth is the "
               "same, so surfaces no kept view sees count as misses.", "",
               _table(["Method", "AP25", "AP50", "AP", "Time (s)"], rows), ""]
        if "ap_vs_views.png" in plots:
            md += [f"![AP vs views]({pd}ap_vs_views.png)", ""]

    if noise_res:
        ns = summary_rows(noise_res, key=lambda r: r.mask_noise)
        noises = [n for n in ("clean", "grounded-sam-like", "harsh") if any(r.mask_noise == n for r in noise_res)]
        rows = []
        for m in methods:
            if not any((m, n) in ns for n in noises):
                continue
            row = [_NAMES.get(m, m)]
            for n in noises:
                s = ns.get((m, n), {})
                row += [_f(s.get("ap25", np.nan)), _f(s.get("ap50", np.nan)), _f(s.get("ap", np.nan))]
            rows.append(row)
        _bold_best(rows, range(1, 1 + 3 * len(noises)))
        md += ["## Mask-noise sweep", "",
               "Same sweep subset and geometry; only the mask candidates change (`clutt3r_core/synth/masks.py`: "
               "`clean` = proper masks only with boundary jitter, `harsh` = more parts, unions, misses and blobs).", "",
               _table(["Method"] + [f"{n} {m}" for n in noises for m in ("AP25", "AP50", "AP")], rows), ""]
        if "ap_vs_noise.png" in plots:
            md += [f"![AP vs noise]({pd}ap_vs_noise.png)", ""]

    # timing and memory
    stages: list[str] = []
    for r in res_main:
        for s, _ in r.stages:
            if s not in stages:
                stages.append(s)
    rows = []
    for m in methods:
        rr = [r for r in res_main if r.method == m]
        row = [_NAMES.get(m, m)] + [_f(_mean(dict(r.stages).get(s, np.nan) for r in rr), 2) for s in stages]
        row += [_f(_mean(r.seconds for r in rr), 2), _f(_mean(r.wall_seconds for r in rr), 2),
                _f(max(r.peak_traced_mb for r in rr), 0), _f(max(r.maxrss_mb for r in rr), 0)]
        rows.append(row)
    md += ["## Time per stage and memory", "",
           "Mean seconds per scene of each stage (– = the method has no such stage), total of the stages, "
           "wall time of the call, peak traced memory (tracemalloc: Python and numpy allocations of one job; "
           "the maximum over scenes) and the worker's peak resident set (maximum over its jobs, MiB).", "",
           _table(["Method"] + stages + ["total", "wall", "peak traced MiB", "max RSS MiB"], rows), ""]
    if "time_per_stage.png" in plots:
        md += [f"![time per stage]({pd}time_per_stage.png)", ""]
    rows = []
    for d in diffs:
        rr = [r for r in res_main if r.method == "ours" and r.difficulty == d]
        if rr:
            rows.append([d, _f(_mean(r.seconds for r in rr), 2), _f(max(r.seconds for r in rr), 2)])
    if rows:
        md += ["Ours, seconds per scene by difficulty:", "", _table(["difficulty", "mean", "max"], rows), ""]

    # per scene
    scenes = sorted(main_scene_names, key=lambda s: ([r.difficulty for r in res_main if r.scene == s][0], s))
    by = {(r.scene, r.method): r for r in res_main}
    rows = []
    for s in scenes:
        any_r = next(r for r in res_main if r.scene == s)
        row = [s, _f(100 * any_r.mean_occlusion, 0), str(any_r.num_gt)]
        for m in methods:
            r = by.get((s, m))
            row.append(f"{_f(r.ap25, 0)} / {_f(r.ap50, 0)} ({r.num_pred})" if r else "–")
        rows.append(row)
    md += breakdown_section(res_main) + depth_section(depth_res, res_main, main.depth_noise)
    md += ["## Per scene", "", "AP25 / AP50 (number of predicted instances); occlusion in percent; GT = objects.", "",
           _table(["scene", "occl.", "GT"] + [_NAMES.get(m, m) for m in methods], rows), ""]
    if notes.strip():
        md += [notes.strip(), ""]
    md += ["## Not in this suite", "",
           "Language-grounded 3D semantic IoU (paper Table II): the metric exists "
           "(`clutt3r_core.evaluation.metrics.semantic_iou`, tested on hand-made cases) but the language "
           "backend does not, so no method is scored on it here.", ""]

    report.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(report, "\n".join(md).encode())
    payload = {"schema_version": 1, "code_version": code_version(), "command": command,
               "elapsed_seconds": None if math.isnan(elapsed) else elapsed, "workers": workers,
               "main_setting": {"views": main.views, "mask_noise": main.mask_noise, "masks": main.masks,
                                "depth_noise": main.depth_noise},
               "results": [r.to_json() for r in all_results]}
    atomic_write_bytes(out / "results.json", json.dumps(payload, indent=1).encode())
    return report
