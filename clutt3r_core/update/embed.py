"""Which embedder the update associates with, and the stored instances' embeddings in it.

S_semantic compares a new mask's embedding with a stored instance's embedding, so both must
come from the same embedder. A run's ``trace.embeddings`` were made with the run's embedder;
when that is the colour histogram (``appearance-hsv``) it cannot tell objects apart (cosine
0.94-0.99 between different objects on the generated pairs, docs/update.md), so the update
uses a learned image embedder when one is installed:

* ``resolve_embedder("auto", state)`` = ``LEARNED`` (``imagenet-minilm``, EfficientNet-Lite0
  features; the ``language`` extra) when it can be built here and the state has a run folder
  to re-embed from, else the state's embedder.
* ``with_embedder(state, name)`` returns the state with its instances' embeddings in
  ``name``'s space: unchanged when it already is; else recomputed from the run's initial views
  and masks with the multi-view instance evidence of ``clutt3r_core.query`` (each instance:
  the area-weighted mean of its masks' unit features, one mask per view, re-normalised), which
  is cached in ``RUN/query_cache.npz`` (the query stage's cache, same key: a text query and an
  update share one pass of the network).

Instance ids of a state are the run's ids (never renumbered), so the rows for a chained state
are the run's rows of its remaining ids.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError

__all__ = ["LEARNED", "AUTO", "RUN", "resolve_embedder", "learned_available", "run_instance_embeddings", "with_embedder"]

LEARNED = "imagenet-minilm"
"""The learned mask embedder used by ``auto`` (the only one that needs no model path)."""
AUTO = "auto"
RUN = "run"
"""The state's own embedder (the default of ``clutt3r update``): on the 12 evaluation pairs the
learned embedder found 3/12 displaced objects against 4/12 with the run's colour histogram, and
did one object worse on sample_seq1 frame 8 (docs/update.md), while costing a re-embedding pass."""


def learned_available() -> bool:
    from clutt3r_core.registry import backend_status

    return any(s.spec.name == LEARNED and s.available for s in backend_status("mask_embedder"))


def resolve_embedder(name: str | None, state) -> str:
    """``auto`` / None -> ``LEARNED`` when installed and the state can be re-embedded (it comes
    from a run folder, or already is in that space), else ``state.embedder``; other names as is."""
    if name == RUN:
        return state.embedder
    if name in (None, "", AUTO):
        ok = learned_available() and (state.run is not None or state.embedder == LEARNED)
        return LEARNED if ok else state.embedder
    return name


def run_instance_embeddings(run_dir: str | Path, embedder=None, name: str | None = None,
                            scene: str | Path | None = None) -> np.ndarray:
    """(K, D) float32 unit embeddings of all K instances of a run folder (rows = run ids) with a
    language backend (``Grounder``: ``embedder`` object or registry ``name``), via the query
    stage's cached multi-view instance evidence (module docstring)."""
    from clutt3r_core.query import RunQuery, create_grounder

    g = embedder if embedder is not None else create_grounder(name)
    if not hasattr(g, "mask_evidence"):
        raise Clutt3rError(f"embedder '{getattr(g, 'name', name)}' has no per-mask evidence "
                           "(clutt3r_core.language.base.Grounder); use the run's own embedder")
    rq = RunQuery.open(run_dir, grounder=g, scene=scene, step=0, corrections=False)  # rows = the run's ids, always
    return np.asarray(rq.instances.features, np.float32)


def with_embedder(state, name: str, embedder=None, scene: str | Path | None = None):
    """``state`` with instance embeddings made by ``name`` (module docstring). Raises
    ``SceneError`` when they must be recomputed but the state has no run folder."""
    if name == state.embedder:
        return state
    if state.run is None:
        raise SceneError(f"the state's embeddings were made with '{state.embedder}'; re-embedding its "
                         f"instances with '{name}' needs the run folder (state.run is None)")
    from clutt3r_core.registry import create_backend

    emb_obj = embedder if embedder is not None else create_backend("mask_embedder", name)
    allrows = run_instance_embeddings(state.run, emb_obj, scene=scene)
    if state.labels is not None and state.labels.entries > 0:  # corrected ids (update.run_labels): mix run rows
        from clutt3r_core.runs import load_run
        from clutt3r_core.update.run_labels import run_labels, run_share

        seg = load_run(state.run)
        lab = run_labels(state.run, seg, entries=state.labels.entries)
        share = run_share(lab.instance, seg, lab.num_ids)
        if share.shape[1] != len(allrows):
            raise SceneError(f"{state.run}: {len(allrows)} instance embeddings for a run of {share.shape[1]} instances")
        rows = share @ allrows
        rows /= np.maximum(np.linalg.norm(rows, axis=1, keepdims=True), 1e-12)
        allrows = rows.astype(np.float32)
    ids = np.asarray(state.instance_ids)
    if len(ids) and int(ids.max()) >= len(allrows):
        raise SceneError(f"state instance ids {ids.tolist()} do not belong to the run {state.run} "
                         f"({len(allrows)} instances)")
    return replace(state, embeddings=allrows[ids], embedder=name)
