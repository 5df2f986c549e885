"""Every leaf pair on which a run disagrees with a reference instance_tree.json, and why.

Usage:
    .venv/bin/python benchmarks/agreement_pairs.py RUN REFERENCE/instance_tree.json [--background-as-instance]

RUN is a run folder of ``clutt3r segment``. Prints both readings of the leaf-pair agreement
(``clutt3r_core.segmentation.compare``), our instances against the reference's over the common
leaves, and each disagreeing pair with the stage that decided it on our side
(``clutt3r_core.explain.explain_pair``: ``merged``, ``background``, ``one_mask_per_view``,
``below_tau_spat`` ...) and its leaf-graph S_spatial; then the counts per (direction, rule) and per
pair of reference instances, which is how docs/benchmark/real-agreement.md was classified (the
masks were then looked at by eye: the rule says what we did, not who is right).
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("reference", type=Path)
    ap.add_argument("--background-as-instance", action="store_true",
                    help="our background leaves count as one instance (the second reading)")
    a = ap.parse_args()

    from clutt3r_core.explain import as_trace, explain_pair
    from clutt3r_core.segmentation.compare import disagreeing_pairs, leaf_pair_agreement, read_leaf2inst

    ours = a.run / "instance_tree.json"
    for bg in (False, True):
        r = leaf_pair_agreement(ours, a.reference, background_as_instance=bg)
        print(f"{'support as one instance' if bg else 'strict':24s} F1 {r.f1:.3f}  P {r.precision:.3f}  "
              f"R {r.recall:.3f}  (common leaves {r.n_common}; ours {r.n_ours}, reference {r.n_reference})")
    mine, ref = read_leaf2inst(ours), read_leaf2inst(a.reference)
    common = sorted(set(mine) & set(ref))
    tab = collections.Counter((mine[k], ref[k]) for k in common)
    cols = sorted({ref[k] for k in common})
    print("\nours \\ reference  " + " ".join(f"{c:>3}" for c in cols))
    for o in sorted({mine[k] for k in common}):
        print(f"{o:>16}  " + " ".join(f"{tab.get((o, c), 0) or '.':>3}" for c in cols))

    trace = as_trace(a.run)
    by_rule: collections.Counter = collections.Counter()
    by_ref: collections.Counter = collections.Counter()
    print()
    for d in disagreeing_pairs(ours, a.reference, a.background_as_instance):
        e = explain_pair(trace, d.a, d.b)
        kind = "ours together, reference apart" if d.ours_same else "reference together, ours apart"
        by_rule[(kind, e.rule)] += 1
        by_ref[tuple(sorted(d.reference))] += 1
        print(f"{d.a[0]}:{d.a[1]:<3} {d.b[0]}:{d.b[1]:<3} ours {d.ours} reference {d.reference}  {kind:31s} "
              f"{e.rule:18s} S_spatial {e.s_spatial:.2f}")
    print("\nby our deciding rule:")
    for (kind, rule), c in by_rule.most_common():
        print(f"  {c:4d}  {kind}: {rule}")
    print("by the reference instances involved:")
    for pair, c in by_ref.most_common():
        print(f"  {c:4d}  reference instances {pair}")


if __name__ == "__main__":
    main()
