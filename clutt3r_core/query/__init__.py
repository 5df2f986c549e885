"""Text queries on instances (Sec. III-D): which instance does a phrase name?

    from clutt3r_core.query import RunQuery
    rq = RunQuery.open("runs/s0")               # loads or computes the run's evidence (cached)
    res = rq.query("the yellow mustard bottle") # QueryResult: scores, ranking, target, confident, why
    res.explanations[res.target].summary()

``RunQuery.open`` takes the default ``text_embedder`` of the registry (the ImageNet +
MiniLM backend when the ``language`` extra is installed) unless ``backend=`` names one.
Evidence per mask is computed once and cached in ``RUN/query_cache.npz``
(``query/evidence.py``); scoring is in ``query/scoring.py``.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError, SceneFileError
from clutt3r_core.language.colors import COLOR_VERSION
from clutt3r_core.query.evidence import (
    CACHE_NAME,
    InstanceEvidence,
    NodeEvidence,
    aggregate_instances,
    compute_node_evidence,
    load_node_evidence,
    refresh_colors,
    refresh_labels,
    run_cache_key,
    save_node_evidence,
)
from clutt3r_core.query.scoring import (
    ClassMatch,
    ColorMatch,
    Explanation,
    QueryConfig,
    QueryResult,
    parse_query,
    score_instances,
)

__all__ = [
    "instance_text_scores",
    "RunQuery",
    "QueryConfig",
    "QueryResult",
    "Explanation",
    "ClassMatch",
    "ColorMatch",
    "parse_query",
    "score_instances",
    "create_grounder",
    "target_points",
]


def instance_text_scores(seg, text_embedding: np.ndarray) -> np.ndarray:
    """(I,) float32: for each instance of ``seg`` (a ``Segmentation``), the best cosine between
    the text embedding and the embeddings of the instance's masks (``seg.trace.embeddings``)."""
    t = np.asarray(text_embedding, np.float32).reshape(-1)
    e = seg.trace.embeddings
    if e.shape[1] != t.shape[0]:
        raise SceneError(f"text embedding has {t.shape[0]} dims but the run's mask embeddings have {e.shape[1]}")
    cos = e @ (t / max(float(np.linalg.norm(t)), 1e-12))
    out = np.full(seg.num_instances, -1.0, np.float32)
    for k in range(seg.num_instances):
        nodes = list(seg.instance_nodes(k))
        if nodes:
            out[k] = cos[nodes].max()
    return out


def create_grounder(name: str | None = None, **kwargs):
    """A language backend from the registry (kind ``text_embedder``) that implements
    ``clutt3r_core.language.base.Grounder``; ``name=None``: the default."""
    from clutt3r_core.language.base import Grounder
    from clutt3r_core.registry import create_backend

    obj = create_backend("text_embedder", name, **kwargs)
    if not isinstance(obj, Grounder):
        raise Clutt3rError(
            f"text embedder '{getattr(obj, 'name', name)}' cannot ground queries in masks "
            "(it does not implement clutt3r_core.language.base.Grounder)"
        )
    return obj


@dataclass(eq=False)
class RunQuery:
    """A run ready for queries: its instance evidence and the backend's text side."""

    run_dir: Path | None
    seg: object
    grounder: object
    evidence: NodeEvidence
    instances: InstanceEvidence
    config: QueryConfig = QueryConfig()

    @classmethod
    def open(
        cls,
        run_dir: str | Path,
        backend: str | None = None,
        scene: str | Path | None = None,
        config: QueryConfig = QueryConfig(),
        progress: bool = False,
        grounder=None,
        use_cache: bool = True,
    ) -> "RunQuery":
        """Open a run folder; compute (with a progress bar if asked) and cache its evidence
        when ``RUN/query_cache.npz`` is absent or stale.

        Args:
            scene: the scene folder, when the run does not record one (older runs).
            grounder: an already built backend (tests, benchmarks), instead of ``backend``.
        """
        from clutt3r_core.runs import is_run_folder, load_run, missing_run_file, run_scene_folder

        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise SceneFileError(run_dir, "no such run folder")
        if not is_run_folder(run_dir):
            raise SceneFileError(missing_run_file(run_dir), "missing: not a clutt3r run folder")
        g = grounder if grounder is not None else create_grounder(backend)
        seg = load_run(run_dir)
        key = run_cache_key(run_dir, g.name, str(getattr(g, "version", "")))
        ev = load_node_evidence(run_dir / CACHE_NAME, key) if use_cache else None

        def scene_of():
            scene_dir = Path(scene) if scene is not None else run_scene_folder(run_dir)
            if scene_dir is None:
                raise SceneFileError(run_dir / "run.json",
                                     "the run records no scene folder; pass --scene SCENE to embed its masks")
            from clutt3r_core.io import load_scene

            return load_scene(scene_dir)

        if ev is None:
            ev = compute_node_evidence(seg, scene_of(), g, progress=progress)
            save_node_evidence(ev, run_dir / CACHE_NAME, key)
        else:
            stale = False
            if ev.color_version != COLOR_VERSION:
                ev, stale = refresh_colors(ev, seg, scene_of()), True
            if ev.labels != (tuple(g.labels) if g.labels is not None else ()):
                ev, stale = refresh_labels(ev, g), True
            if stale:
                save_node_evidence(ev, run_dir / CACHE_NAME, key)
        return cls.from_evidence(seg, g, ev, config, run_dir)

    @classmethod
    def from_evidence(cls, seg, grounder, ev: NodeEvidence, config: QueryConfig = QueryConfig(),
                      run_dir: Path | None = None) -> "RunQuery":
        inst = aggregate_instances(seg, ev, label_mode=ev.label_embeddings is not None)
        return cls(run_dir, seg, grounder, ev, inst, config)

    @classmethod
    def from_scene(cls, seg, scene, grounder, config: QueryConfig = QueryConfig(), progress: bool = False) -> "RunQuery":
        """In memory, without a run folder (benchmarks, tests)."""
        return cls.from_evidence(seg, grounder, compute_node_evidence(seg, scene, grounder, progress), config)

    def query(self, text: str) -> QueryResult:
        t0 = time.perf_counter()
        q = parse_query(text)
        emb = self.grounder.embed_text([q.name])[0] if q.name else None
        res = score_instances(self.instances, q, emb, self.config, self.evidence.label_embeddings,
                              self.evidence.labels, self.evidence.backend)
        return _with_time(res, time.perf_counter() - t0)


def _with_time(res: QueryResult, t: float) -> QueryResult:
    from dataclasses import replace

    return replace(res, time_s=t)


def target_points(seg, target: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) float32 points and (P, 3) uint8 colours of instance ``target``."""
    sel = seg.instance == int(target)
    return seg.points[sel].astype(np.float32), seg.colors[sel].astype(np.uint8)
