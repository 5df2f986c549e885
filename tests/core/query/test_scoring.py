"""Query scoring (query/scoring.py) on hand-made instance evidence: the pure part of Sec. III-D."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import Clutt3rError
from clutt3r_core.language.colors import COLOR_WORDS
from clutt3r_core.query import QueryConfig, parse_query, score_instances
from clutt3r_core.query.evidence import InstanceEvidence

LABELS = ("banana", "coffee mug", "soccer ball", "tennis ball")
LAB_EMB = np.eye(4, dtype=np.float32)


def _inst(probs, colors=None) -> InstanceEvidence:
    p = np.asarray(probs, np.float64)
    p = p / p.sum(axis=1, keepdims=True)
    k = len(p)
    c = np.zeros((k, len(COLOR_WORDS)), np.float32)
    if colors is not None:
        for i, (w, s) in enumerate(colors):
            c[i, COLOR_WORDS.index(w)] = s
            c[i, COLOR_WORDS.index("grey")] = 1 - s
    return InstanceEvidence(np.log(p).astype(np.float32), c, np.eye(k, 8, dtype=np.float32), np.ones(k, np.int32))


def test_the_named_class_wins_and_is_explained():
    inst = _inst([[0.7, 0.1, 0.1, 0.1], [0.1, 0.7, 0.1, 0.1], [0.1, 0.1, 0.7, 0.1]])
    res = score_instances(inst, parse_query("the coffee mug"), LAB_EMB[1], QueryConfig(), LAB_EMB, LABELS, "fake")
    assert res.target == 1 and res.ranking[0] == 1 and res.confident
    ex = res.explanations[1]
    assert ex.classes[0].label == "coffee mug" and ex.classes[0].probability == pytest.approx(0.7, abs=1e-5)
    assert ex.looks_like[0].label == "coffee mug"
    assert "coffee mug" in ex.summary()


def test_a_confident_class_does_not_win_every_query():
    # instance 0 is very sure of "banana"; a query for "soccer ball" must still pick instance 1, whose
    # (less confident) probability of soccer ball is the highest (the failure of sum_c p(c) cos)
    inst = _inst([[0.97, 0.01, 0.01, 0.01], [0.3, 0.1, 0.4, 0.2], [0.25, 0.25, 0.25, 0.25]])
    res = score_instances(inst, parse_query("soccer ball"), LAB_EMB[2], QueryConfig(), LAB_EMB, LABELS)
    assert res.target == 1


def test_colour_words_decide_between_equal_names():
    inst = _inst([[0.25] * 4, [0.25] * 4, [0.25] * 4], colors=[("red", 0.8), ("yellow", 0.9), ("blue", 0.7)])
    res = score_instances(inst, parse_query("the yellow one"), None, QueryConfig(), LAB_EMB, LABELS)
    assert res.target == 1
    assert res.explanations[1].colors[0].word == "yellow"
    assert res.explanations[1].colors[0].share == pytest.approx(0.9)
    assert res.explanations[1].color_score == pytest.approx(QueryConfig().color_weight * 0.9)


def test_nothing_matches_is_not_confident():
    inst = _inst([[0.25] * 4] * 4)
    res = score_instances(inst, parse_query("giraffe"), LAB_EMB[0], QueryConfig(), LAB_EMB, LABELS)
    assert res.target is not None and not res.confident


def test_no_instances():
    inst = InstanceEvidence(np.zeros((0, 4), np.float32), np.zeros((0, len(COLOR_WORDS)), np.float32),
                            np.zeros((0, 8), np.float32), np.zeros(0, np.int32))
    res = score_instances(inst, parse_query("mug"), LAB_EMB[1], QueryConfig(), LAB_EMB, LABELS)
    assert res.target is None and res.ranking == () and not res.confident
    assert res.to_json()["target"] is None


def test_shared_space_mode_is_cosine():
    g = np.array([[1, 0, 0], [0.6, 0.8, 0], [0, 0, 1]], np.float32)
    inst = InstanceEvidence(g, np.zeros((3, len(COLOR_WORDS)), np.float32), g, np.ones(3, np.int32))
    res = score_instances(inst, parse_query("x"), np.array([0, 1, 0.1], np.float32))
    assert res.ranking == (1, 2, 0)
    assert res.explanations[1].classes == ()


@pytest.mark.parametrize("bad", ["", "   ", "\n"])
def test_empty_query_is_refused(bad):
    with pytest.raises(Clutt3rError, match="empty query"):
        parse_query(bad)


def test_parse_strips_fillers_and_colours():
    q = parse_query("Please pick the yellow mustard bottle")
    assert q.name == "mustard bottle" and q.colors == ("yellow",)


@settings(max_examples=80, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(1, 7))
def test_result_invariants(seed, k):
    rng = np.random.default_rng(seed)
    inst = _inst(rng.random((k, 4)) + 1e-3, colors=[("red", float(rng.random()))] * k)
    res = score_instances(inst, parse_query("red banana"), rng.normal(size=4).astype(np.float32),
                          QueryConfig(), LAB_EMB, LABELS)
    assert sorted(res.ranking) == list(range(k))
    assert np.all(np.diff(res.scores[list(res.ranking)]) <= 1e-6)  # best first
    assert res.target == res.ranking[0]
    d = json.loads(json.dumps(res.to_json()))
    assert set(d) == {"query", "ranking", "target", "confident", "time_s"}
    assert [r["instance"] for r in d["ranking"]] == list(res.ranking)
    # the z-scored name term has mean 0 over the scene
    assert abs(np.mean([e.name_score for e in res.explanations])) < 1e-6
