"""Scoring a text query against a run's instance evidence (Sec. III-D, target identification).

A query's score for instance k is a *name term* plus a *colour term*:

* name term, label mode (ImageNet backend): the query without its colour words is
  embedded with the text model and compared with the 1000 class names; a softmax of
  those similarities at temperature ``temperature`` gives a distribution q over classes,
  and the raw score is ``sum_c q(c) * L_k(c)``, with L_k the instance's mean
  log-probability over its views. Why not ``sum_c p_k(c) cos(query, c)``: one confident
  class then wins every query (earlier measurement in the issue: top-1 0.26 against 0.44).
  Shared-space mode (CLIP-like backends): the raw score is the cosine of the query's
  embedding and the instance's aggregated embedding.
  The raw scores are z-scored over the scene's instances, so the term says how much
  better than the other objects an instance fits the name.
* colour term: ``color_weight`` times the mean, over the colour words the query names,
  of the instance's share of mask pixels of that colour.

``confident`` is false when the best score is not clearly above the rest: the rule and
its threshold are in ``QueryConfig`` and were measured with ``benchmarks/bench_query.py``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneError
from clutt3r_core.language.colors import COLOR_WORDS, colors_in_text, strip_colors
from clutt3r_core.query.evidence import InstanceEvidence

__all__ = [
    "QueryConfig",
    "ClassMatch",
    "ColorMatch",
    "Explanation",
    "QueryResult",
    "TextQuery",
    "parse_query",
    "score_instances",
]

_NOUN_COLORS = {"orange"}
_FILLER = {"the", "a", "an", "this", "that", "please", "pick", "grab", "get", "find", "me", "up", "one", "object"}


@dataclass(frozen=True)
class QueryConfig:
    """Settings of query scoring; each measured in ``benchmarks/bench_query.py``."""

    temperature: float = 0.05
    """Softmax temperature over the query-to-class-name cosines (label mode). The issue's
    earlier measurement: 0.05; ours on generated scenes agrees (bench_query)."""
    color_weight: float = 3.0
    """Weight of the colour term (a share in 0..1) against the z-scored name term (ours:
    bench_query sweep on 6 generated scenes, colour + name top-1: 1.0 -> 0.59, 2.0 -> 0.71,
    3.0 -> 0.72 with the name gate)."""
    confident_margin: float = 1.0
    """``confident`` iff the best instance's score exceeds the runner-up's by this much AND
    its name-or-colour evidence is positive. Measured (bench_query --margins, 6 generated
    scenes): at 1.0 a query for an absent object is called confident 10 % of the time
    (0.5: 37 %), and confident answers are right 86 % of the time for names and for
    colour + name (0.5: 65 % / 79 %); 48 % of colour + name queries are confident."""
    center: bool = False
    """Label mode: compare the query with each instance's log-probabilities minus their mean
    over the classes (a vague query, q spread over many classes, otherwise favours the
    instance whose prediction is flattest). Measured (bench_query sweep): no gain on names
    (0.41 vs 0.40 top-1) and a loss with colours (0.69 vs 0.72), so off."""
    name_gate: float = 0.45
    """Label mode: the name term is scaled by clip((m - name_gate) / 0.3, 0, 1), m the best
    cosine of the query's name with a class name; a name the image model has no class for
    ("plum" -> "plunger") then weighs little and colour words decide. 0 = off. Measured
    (bench_query sweep): colour + name top-1 0.62 -> 0.71, top-3 0.90 -> 0.95; names alone
    unchanged (0.40); absent names called confident 0.50 -> 0.37."""
    explain_classes: int = 3
    """Class names listed in each instance's explanation."""

    def __post_init__(self) -> None:
        if not self.temperature > 0:
            raise SceneError(f"QueryConfig.temperature must be > 0, got {self.temperature}")
        if self.color_weight < 0:
            raise SceneError(f"QueryConfig.color_weight must be >= 0, got {self.color_weight}")


@dataclass(frozen=True)
class TextQuery:
    """A parsed query: the text, its object-name part and the colour words it names."""

    text: str
    name: str
    colors: tuple[str, ...]


def parse_query(text: str) -> TextQuery:
    """Split a query into its name part (colour words and fillers removed) and colour words.

    Raises ``Clutt3rError`` for an empty query."""
    if not isinstance(text, str) or not text.strip():
        raise Clutt3rError("empty query: say what to look for, e.g. \"the yellow mustard bottle\"")
    words = [w for w in re.findall(r"[A-Za-z0-9'-]+", text) if w.lower() not in _FILLER]
    colors = colors_in_text(text)
    # a colour word is an adjective, except a colour that is also a thing ("orange") at the end
    # of the phrase: "the orange" names the fruit (and still counts as the colour)
    name = [w for i, w in enumerate(words)
            if not colors_in_text(w) or (i == len(words) - 1 and w.lower() in _NOUN_COLORS)]
    return TextQuery(text=text.strip(), name=" ".join(name), colors=colors)


@dataclass(frozen=True)
class ClassMatch:
    """A class name the query points at, and how much the instance looks like it."""

    label: str
    query_weight: float
    """q(c): the share of the query's softmax on this class name."""
    probability: float
    """The instance's geometric-mean probability of the class over its views."""


@dataclass(frozen=True)
class ColorMatch:
    word: str
    share: float
    """Share of the instance's mask pixels with this colour (weighted over views)."""
    contribution: float
    """What it added to the score (``color_weight * share / n_colour_words``)."""


@dataclass(frozen=True)
class Explanation:
    """Why an instance got its score (what the viewer shows)."""

    name_score: float
    """z-scored name term (0 when the query has no name part)."""
    color_score: float
    classes: tuple[ClassMatch, ...]
    """Label mode: the query's top class names with this instance's probabilities."""
    looks_like: tuple[ClassMatch, ...]
    """Label mode: this instance's own most probable classes (query_weight = q of that class)."""
    colors: tuple[ColorMatch, ...]
    dominant_colors: tuple[tuple[str, float], ...]
    """The instance's two largest colour shares."""

    def summary(self) -> str:
        parts = []
        if self.classes:
            c = self.classes[0]
            parts.append(f"name {self.name_score:+.2f} ('{c.label.split(',')[0]}' p={c.probability:.3f})")
        elif self.name_score:
            parts.append(f"name {self.name_score:+.2f}")
        for m in self.colors:
            parts.append(f"{m.word} {m.share:.0%} (+{m.contribution:.2f})")
        if self.looks_like:
            parts.append("looks like " + ", ".join(f"{x.label.split(',')[0]} {x.probability:.2f}" for x in self.looks_like[:2]))
        return "; ".join(parts)


@dataclass(frozen=True)
class QueryResult:
    """The answer to one text query on a run.

    Attributes:
        query: the query text.
        scores: (I,) float32 score per instance id (ids of the run's instances.npz).
        ranking: instance ids, best first (every instance).
        target: the best instance id, None when the run has no instance.
        confident: whether the target clearly matches (``QueryConfig.confident_margin``).
        explanations: one per instance id.
        backend: the language backend's name.
        time_s: seconds spent answering (text embedding and scoring; not loading models).
    """

    query: str
    scores: np.ndarray
    ranking: tuple[int, ...]
    target: int | None
    confident: bool
    explanations: tuple[Explanation, ...]
    backend: str
    time_s: float = 0.0
    name_match: float = float("nan")
    """Label mode: best cosine of the query's name with a label (1 = the name is a class)."""
    step: int = 0
    """Updates of the run's chain applied to the scene queried (0 = the run as segmented)."""
    scene: str = ""
    """The scene queried, e.g. "scene after update 2 (frame 9)"; "" for a run without updates.
    In an updated scene, ids not in it (removed, or added but not described) score NaN and are
    not in ``ranking``."""

    def __post_init__(self) -> None:
        ranked = np.flatnonzero(np.isfinite(self.scores)) if self.scene else np.arange(len(self.scores))
        if self.scores.shape != (len(self.explanations),) or sorted(self.ranking) != ranked.tolist():
            raise SceneError("QueryResult: one score and one explanation per instance; ranking is a permutation "
                             "of the instances scored")

    def to_json(self) -> dict:
        """The CLI's JSON object (``clutt3r query --json``)."""
        return {
            "query": self.query,
            "ranking": [{"instance": int(i), "score": round(float(self.scores[i]), 4)} for i in self.ranking],
            "target": None if self.target is None else int(self.target),
            "confident": bool(self.confident),
            "time_s": round(float(self.time_s), 4),
        } | ({"step": int(self.step), "scene": self.scene} if self.scene else {})


def _zscore(x: np.ndarray) -> np.ndarray:
    if len(x) < 2:
        return np.zeros_like(x)
    sd = float(x.std())
    return (x - x.mean()) / sd if sd > 1e-9 else np.zeros_like(x)


def score_instances(
    inst: InstanceEvidence,
    query: TextQuery,
    name_embedding: np.ndarray | None,
    config: QueryConfig = QueryConfig(),
    label_embeddings: np.ndarray | None = None,
    labels: tuple[str, ...] = (),
    backend: str = "",
) -> QueryResult:
    """Score every instance for ``query`` (pure; see module docstring).

    Args:
        inst: the run's aggregated instance evidence.
        query: parsed query (``parse_query``).
        name_embedding: (Dt,) text embedding of ``query.name``; None when the name is empty.
        label_embeddings: (L, Dt) unit embeddings of ``labels`` (label mode), else None.
    """
    k = inst.num_instances
    raw = np.zeros(k, np.float64)
    q = None
    name_match = float("nan")
    if name_embedding is not None and k:
        t = np.asarray(name_embedding, np.float64).reshape(-1)
        t = t / max(float(np.linalg.norm(t)), 1e-12)
        if label_embeddings is not None:
            cos = label_embeddings.astype(np.float64) @ t
            name_match = float(cos.max())
            s = cos / config.temperature
            q = np.exp(s - s.max())
            q /= q.sum()
            lp = inst.grounding.astype(np.float64)
            if config.center:
                lp = lp - lp.mean(axis=1, keepdims=True)
            raw = lp @ q
        else:
            if inst.grounding.shape[1] != t.shape[0]:
                raise SceneError(f"text embedding has {t.shape[0]} dims, instance evidence {inst.grounding.shape[1]}")
            raw = inst.grounding.astype(np.float64) @ t
    name = _zscore(raw)
    if q is not None and config.name_gate > 0:
        name = name * float(np.clip((name_match - config.name_gate) / 0.3, 0.0, 1.0))
    cidx = [COLOR_WORDS.index(c) for c in query.colors]
    share = inst.colors[:, cidx].astype(np.float64) if cidx else np.zeros((k, 0))
    color = config.color_weight * share.mean(axis=1) if cidx else np.zeros(k)
    score = name + color
    ranking = tuple(int(i) for i in np.argsort(-score, kind="stable"))
    target = ranking[0] if k else None
    confident = False
    if k:
        best = score[ranking[0]]
        second = score[ranking[1]] if k > 1 else best - np.inf
        evidence = name[ranking[0]] > 0 or (cidx and share[ranking[0]].mean() > 0.25)
        confident = bool(best - second >= config.confident_margin and evidence)
    expl = []
    n_ex = config.explain_classes
    top_q = np.argsort(-q)[:n_ex] if q is not None else ()
    if q is not None and labels and k:
        probs = np.exp(inst.grounding.astype(np.float64))  # (I, L), once for every instance
        part = np.argpartition(-probs, min(3, probs.shape[1] - 1), axis=1)[:, :3]
    for i in range(k):
        classes: tuple[ClassMatch, ...] = ()
        looks: tuple[ClassMatch, ...] = ()
        if q is not None and labels:
            p = probs[i]
            classes = tuple(ClassMatch(labels[c], float(q[c]), float(p[c])) for c in top_q)
            top = part[i][np.argsort(-p[part[i]])]
            looks = tuple(ClassMatch(labels[c], float(q[c]), float(p[c])) for c in top)
        cols = tuple(
            ColorMatch(w, float(share[i, j]), float(config.color_weight * share[i, j] / len(cidx)))
            for j, w in enumerate(query.colors)
        )
        dom = np.argsort(-inst.colors[i])[:2]
        expl.append(Explanation(float(name[i]), float(color[i]), classes, looks, cols,
                                tuple((COLOR_WORDS[c], float(inst.colors[i, c])) for c in dom)))
    return QueryResult(query.text, score.astype(np.float32), ranking, target, confident, tuple(expl), backend,
                       name_match=name_match)
