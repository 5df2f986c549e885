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
    "corrected_evidence",
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
    scene: object = None
    """The ``update.scene_after.SceneAfter`` queried when the run has updates (None: a run
    without updates, queried as segmented)."""
    described: frozenset = frozenset()
    """Added instance ids the backend described (their mask in the post view); the others
    present in ``scene`` cannot be ranked."""
    labelling: object = None
    """At step 0 of a run whose correction log changes its labels: the labelling queried
    (``update.run_labels.StepZeroLabels``; ``scene`` is then the run in those ids, ``instances``
    their evidence). None: the run's own ids, or the scene after updates."""

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
        step: int | None = None,
        corrections: bool = True,
        seg=None,
    ) -> "RunQuery":
        """Open a run folder; compute (with a progress bar if asked) and cache its evidence
        when ``RUN/query_cache.npz`` is absent or stale.

        Args:
            scene: the scene folder, when the run does not record one (older runs).
            grounder: an already built backend (tests, benchmarks), instead of ``backend``.
            step: when the run has updates (``RUN/updates``), the scene after that many of them
                (None: all; 0: the run as segmented); removed instances are not ranked, added
                ones are described from their mask in the post view. A step the chain does not
                have is one clear error.
            corrections: at step 0, rank the ids of the run's correction log (the Edit tab's:
                ``update.run_labels.step_zero_labels``; deleted and merged ids are not ranked, a
                merge's evidence mixes its parts', ``corrected_evidence``), as the update chain
                does after step 0. False: the run's own ids whatever its log (rows = run
                instances, for the update's re-embedding, which mixes them itself).
            seg: the run's ``pipeline.Segmentation`` when already loaded (``clutt3r grasp QUERY``).
        """
        from clutt3r_core.update.scene_after import resolve_step

        from clutt3r_core.runs import is_run_folder, load_run, missing_run_file, run_scene_folder

        run_dir = Path(run_dir)
        if not run_dir.is_dir():
            raise SceneFileError(run_dir, "no such run folder")
        if not is_run_folder(run_dir):
            raise SceneFileError(missing_run_file(run_dir), "missing: not a clutt3r run folder")
        step = resolve_step(run_dir, step)  # a bad --step fails before any model loads
        g = grounder if grounder is not None else create_grounder(backend)
        seg = load_run(run_dir) if seg is None else seg
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
        rq = cls.from_evidence(seg, g, ev, config, run_dir)
        if step == 0 and corrections:
            from clutt3r_core.update.run_labels import step_zero_labels

            z = step_zero_labels(seg, run_dir)
            if z.corrected:
                return rq.with_labelling(z)
        return rq._after_updates(step, scene_of, scene)

    def with_labelling(self, z) -> "RunQuery":
        """This run query (rows = the run's instances) on the corrected labelling ``z`` at step 0
        (``update.run_labels.StepZeroLabels``): its evidence carried to the corrected ids
        (``corrected_evidence`` over ``z.share``, as after an update), and ``scene`` the run's cloud
        in those ids (``SceneAfter`` at step 0: ``present`` = the ids with points, not deleted or
        merged), so ``query`` ranks them and ``target_points`` reads their points. ``z`` with the
        run's own ids: itself."""
        from dataclasses import replace

        from clutt3r_core.update.scene_after import ChainInputs, build_scene_after, chain_length

        if not z.corrected:
            return self
        seg, lab = self.seg, z.labels
        inst = corrected_evidence(self.instances, z.share, self.evidence.label_embeddings is not None)
        sa = build_scene_after(ChainInputs(
            points=seg.points, colors=seg.colors, normals=seg.normals, instance=lab.instance, ids=lab.ids,
            num_ids=lab.num_ids, n_updates=chain_length(self.run_dir) if self.run_dir is not None else 0,
            run=self.run_dir, run_share=z.share))
        return replace(self, scene=sa, instances=inst, labelling=z)

    def _after_updates(self, step: int, scene_of, scene: str | Path | None = None) -> "RunQuery":
        """This run query on the scene after ``step`` updates (itself when the run has none); the
        added instances' normals as ``clutt3r grasp`` has them (``scene_after.post_eyes``)."""
        from dataclasses import replace

        from clutt3r_core.query.added import added_instance_evidence
        from clutt3r_core.update.scene_after import added_masks, chain_length, post_eyes, scene_after

        if self.run_dir is None or chain_length(self.run_dir) == 0:
            return self
        sa = scene_after(self.run_dir, step, seg=self.seg, eyes=post_eyes(self.run_dir, step, scene))
        adds = [a for a in added_masks(self.run_dir, step) if a[0] in sa.added]
        inst, done = self.instances, frozenset()
        if sa.run_share is not None:  # the chain's ids are the Edit tab's corrected ones (update.run_labels)
            inst = corrected_evidence(inst, sa.run_share, self.evidence.label_embeddings is not None)
        if adds:
            try:
                sc = scene_of()
            except Clutt3rError:
                sc = None  # no scene folder: the added instances stay unranked (the result says so)
            inst, done = added_instance_evidence(inst, self.evidence, self.grounder, sc, adds)
        return replace(self, scene=sa, instances=inst, described=done)

    @classmethod
    def from_evidence(cls, seg, grounder, ev: NodeEvidence, config: QueryConfig = QueryConfig(),
                      run_dir: Path | None = None) -> "RunQuery":
        inst = aggregate_instances(seg, ev, label_mode=ev.label_embeddings is not None)
        return cls(run_dir, seg, grounder, ev, inst, config)

    @classmethod
    def from_scene(cls, seg, scene, grounder, config: QueryConfig = QueryConfig(), progress: bool = False) -> "RunQuery":
        """In memory, without a run folder (benchmarks, tests)."""
        return cls.from_evidence(seg, grounder, compute_node_evidence(seg, scene, grounder, progress), config)

    def ranked_ids(self) -> np.ndarray:
        """(K,) int ids a query ranks: every run instance, or in an updated scene the ones
        present (run instances not removed, added ones the backend described)."""
        if self.scene is None:
            return np.arange(self.instances.num_instances)
        sa = self.scene
        return np.array([k for k in sa.present.tolist() if k not in sa.added or k in self.described], np.int64)

    def query(self, text: str) -> QueryResult:
        if self.scene is not None:
            sa = self.scene
            label = self.labelling.describe() if self.labelling is not None else sa.label
            return self.query_among(text, self.ranked_ids(), sa.step, label, int(sa.present.max(initial=-1)) + 1)
        t0 = time.perf_counter()
        q = parse_query(text)
        emb = self.grounder.embed_text([q.name])[0] if q.name else None
        res = score_instances(self.instances, q, emb, self.config, self.evidence.label_embeddings,
                              self.evidence.labels, self.evidence.backend)
        return _with_time(res, time.perf_counter() - t0)

    def query_among(self, text: str, ids, step: int, scene: str, n_ids: int = 0) -> QueryResult:
        """``text`` ranked among the instance ids ``ids`` only (rows of ``instances``): the ones
        in the scene after ``step`` updates, named ``scene`` ("scene after update 2 (frame 9)").
        ``scores`` covers ids 0..max(n_ids, rows) - 1, NaN outside ``ids``. ``query`` calls it
        for ``self.scene``; the viewer's Query tab for the scene it shows (the same scores)."""
        t0 = time.perf_counter()
        q = parse_query(text)
        emb = self.grounder.embed_text([q.name])[0] if q.name else None
        # only the instances in the scene are scored (the name term is z-scored over them, so a
        # removed object does not shift the others' scores), then mapped back to ids
        ids = np.asarray(ids, np.int64)
        e = self.instances
        sub = InstanceEvidence(e.grounding[ids], e.colors[ids], e.features[ids], e.n_views[ids])
        r = score_instances(sub, q, emb, self.config, self.evidence.label_embeddings,
                            self.evidence.labels, self.evidence.backend)
        n = max(e.num_instances, int(n_ids))
        scores = np.full(n, np.nan, np.float32)
        scores[ids] = r.scores
        nan = float("nan")
        expl = [Explanation(nan, nan, (), (), (), ())] * n
        for j, k in enumerate(ids):
            expl[int(k)] = r.explanations[j]
        ranking = tuple(int(ids[j]) for j in r.ranking)
        res = QueryResult(r.query, scores, ranking, ranking[0] if ranking else None, r.confident, tuple(expl),
                          r.backend, name_match=r.name_match, step=int(step), scene=scene)
        return _with_time(res, time.perf_counter() - t0)


def corrected_evidence(e: InstanceEvidence, share: np.ndarray, label_mode: bool) -> InstanceEvidence:
    """Run-instance evidence carried to corrected ids: each id's rows mixed by the share of its
    points each run instance had (a merge mixes its parts, a split-off part keeps its source's;
    the same rule as the update's stored embeddings, ``update.state.state_from_segmentation``)."""
    g = (share @ e.grounding).astype(np.float32)
    if not label_mode:  # shared space: directions, as aggregate_instances
        g /= np.maximum(np.linalg.norm(g, axis=1, keepdims=True), 1e-12)
    f = (share @ e.features).astype(np.float32)
    f /= np.maximum(np.linalg.norm(f, axis=1, keepdims=True), 1e-12)
    n = np.array([int(e.n_views[r > 0].max(initial=0)) for r in share], np.int32)
    return InstanceEvidence(g, (share @ e.colors).astype(np.float32), f, n)


def _with_time(res: QueryResult, t: float) -> QueryResult:
    from dataclasses import replace

    return replace(res, time_s=t)


def target_points(seg, target: int) -> tuple[np.ndarray, np.ndarray]:
    """(P, 3) float32 points and (P, 3) uint8 colours of instance ``target``."""
    sel = seg.instance == int(target)
    return seg.points[sel].astype(np.float32), seg.colors[sel].astype(np.uint8)
