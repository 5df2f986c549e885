"""The demo's story (clutt3r_core.demo) and the tour's steps (clutt3r_viewer.tour) without a browser."""

from __future__ import annotations

import json
import time
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.demo import DEMO_JSON, DemoStory, QueryChoice, StageTime, build_demo, choose_query, load_story
from clutt3r_viewer.tour import STEPS, facts_of, focus_points, replay_event, step_camera, tree_node, tree_view
from tests.viewer._tour_demo import TINY, language_available, tiny_demo_dir

SAMPLE = __import__("pathlib").Path(__file__).resolve().parents[3] / "shared/data/clutt3r-samples/sample_seq1/data"


@pytest.fixture(scope="module")
def demo_run(tmp_path_factory):
    return tiny_demo_dir(tmp_path_factory)


def test_the_demo_tells_the_whole_story(demo_run):
    s = load_story(demo_run)
    assert s is not None and s.generated and s.post_frames
    # the update found what the generator did (ground truth): the object taken away and the one pushed
    assert s.true_removed in s.removed and s.true_displaced in s.displaced
    assert (demo_run / "updates").is_dir() and (demo_run / "scene").is_dir()
    if not language_available():
        pytest.skip("the language extra is not installed: no suggested query (pip install -e '.[language]')")
    q = s.query
    assert s.complete and q is not None
    # measured, not assumed: the phrase was queried and ranked its intended object first
    assert q.correct and q.target == q.intended and (q.text, q.target) in q.tried
    assert s.grasp_target == q.target and s.n_grasps > 0 and (demo_run / "grasps.npz").is_file()
    from clutt3r_core.query import RunQuery

    # the run's own query agrees, on the scene as segmented (the story queries before the grasp) ...
    assert RunQuery.open(demo_run, step=0).query(q.text).target == q.target
    # ... and after the update the object it took away is no longer ranked (the scene now)
    if q.target in s.removed:
        after = RunQuery.open(demo_run).query(q.text)
        assert after.step == 1 and after.target != q.target and np.isnan(after.scores[q.target])


def test_a_second_demo_reads_the_run_back(demo_run):
    before = {p: p.stat().st_mtime_ns for p in (demo_run / "instances.npz", demo_run / DEMO_JSON)}
    t0 = time.perf_counter()
    s = build_demo(demo_run, TINY, with_query=language_available(), log=lambda m: None)
    assert time.perf_counter() - t0 < 2.0  # nothing recomputed (a build takes tens of seconds)
    assert all(st.cached for st in s.stages)
    assert {p: p.stat().st_mtime_ns for p in before} == before
    # another configuration is another demo: the cache does not answer it
    other = replace(TINY, seed=TINY.seed + 1)
    assert json.loads((demo_run / DEMO_JSON).read_text())["key"] != other.key()


def test_story_round_trips_through_json(demo_run):
    s = load_story(demo_run)
    back = DemoStory.from_json(json.loads(json.dumps(s.to_json())))
    assert back.query == s.query and back.removed == s.removed and back.post_frames == s.post_frames
    assert [x.stage for x in back.stages] == [x.stage for x in s.stages]


def test_a_damaged_story_is_one_clear_error(tmp_path):
    from clutt3r_core.errors import SceneFileError

    (tmp_path / DEMO_JSON).write_text("{not json")
    with pytest.raises(SceneFileError, match="demo.json"):
        load_story(tmp_path)
    assert load_story(tmp_path / "nothing") is None


class _FakeQuery:
    """rq.query(text) -> an object whose target is table[text]."""

    def __init__(self, table, confident=True):
        self.table, self.confident = table, confident

    def query(self, text):
        return SimpleNamespace(target=self.table.get(text), confident=self.confident)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 4), st.integers(0, 4)), min_size=1, max_size=8))
def test_choose_query_picks_a_correct_phrase_whenever_one_exists(pairs):
    # phrase i is meant for pairs[i][0] and the query ranks pairs[i][1] first
    table = {f"p{i}": t for i, (_, t) in enumerate(pairs)}
    cands = [(k, [f"p{i}"], "test") for i, (k, _) in enumerate(pairs)]
    c = choose_query(_FakeQuery(table), cands)
    exists = any(k == t for k, t in pairs)
    assert c.correct == exists
    if exists:  # the first correct one, in the order of preference
        first = next(i for i, (k, t) in enumerate(pairs) if k == t)
        assert c.text == f"p{first}" and c.target == c.intended
    assert len(c.tried) <= len(pairs)
    assert choose_query(_FakeQuery({}), []) is None


def test_steps_are_the_story_in_order():
    keys = [s.key for s in STEPS]
    assert keys == ["views", "tree", "replay", "instances", "query", "grasps", "removed", "pose"]
    assert len(set(keys)) == len(keys)
    from clutt3r_viewer.layers import COLOR_LAYERS
    from clutt3r_viewer.panels import PANELS

    tabs = {p.tab for p in PANELS}
    names = {layer.name for layer in COLOR_LAYERS}
    for s in STEPS:
        assert s.tab in tabs and s.colour in names, s


def test_every_sentence_is_filled_from_the_run(tiny_data):
    d = tiny_data
    story = DemoStory(run=None, scene=None, generated=True,
                      query=QueryChoice("red mug", 1, 1, True, True, (("red mug", 1),), "test"), grasp_target=1,
                      n_grasps=3, post_frames=(8,), removed=(1,), displaced=(0,), true_removed=1, true_displaced=0,
                      stages=(StageTime("scene", 1.0),))
    v = tree_view(d)
    node = tree_node(d, v)
    assert 0 <= v < len(d.trace.frames) and node >= 0 and int(d.trace.nodes.view[node]) == v
    ev = replay_event(d)
    assert 1 <= ev <= d.num_events
    f = facts_of(d, story, v, node, ev, 12)
    for s in STEPS:
        text = s.text.format(**f.__dict__)
        assert "{" not in text and f.has(s.needs), s.key
    assert "red mug" in STEPS[4].text.format(**f.__dict__)
    empty = facts_of(d, None, v, node, ev, 0)
    assert not empty.has("query") and not empty.has("pose") and empty.has("")


def test_each_step_points_the_camera_somewhere_sensible(tiny_data):
    d = tiny_data
    seen = []
    for s in STEPS:
        focus = focus_points(d, int(np.argmax(np.bincount(d.seg.instance[d.seg.instance >= 0]))))
        pose = step_camera(d, s, 1, focus)
        eye, at = np.asarray(pose.position), np.asarray(pose.look_at)
        assert np.all(np.isfinite(eye)) and eye[2] > at[2] and 0.05 < np.linalg.norm(eye - at) < 5
        seen.append((s.camera, tuple(np.round(eye, 4))))
    # the three kinds of camera are three different places
    assert len({e for c, e in seen if c in ("overview",)}) == 1
    assert len({e for _, e in seen}) >= 3
    assert focus_points(d, -1) is None
    k = int(d.seg.instance.max())
    moved = focus_points(d, k, d.seg.points[d.seg.instance == k] + 0.1)
    assert len(moved) == 2 * int((d.seg.instance == k).sum())


@pytest.mark.realdata
@pytest.mark.slow
def test_demo_on_the_real_sample_updates_from_its_post_grasp_frames(tmp_path):
    if not SAMPLE.is_dir():
        pytest.skip(f"real sample not found at {SAMPLE} (../shared/data/clutt3r-samples/sample_seq1); skipped")
    from clutt3r_core.demo import DemoConfig

    # frame 8 only (the chain to frame 9 is what `clutt3r update` tests; docs/demo.md has the full demo)
    s = build_demo(tmp_path / "seq1", DemoConfig(scene=SAMPLE, max_post_frames=1), with_query=False, log=lambda m: None)
    assert s.post_frames == (8,) and not s.generated and s.true_removed == -1
    assert len(list((tmp_path / "seq1" / "updates").glob("*/update.json"))) == 1
    assert s.removed  # frame 8 is after a grasp: something is gone


def test_export_html_command_writes_a_page_and_refuses_a_non_run(demo_run, tmp_path, capfd):
    from clutt3r_core.cli import available_commands, main

    assert "export-html" in available_commands()
    out = tmp_path / "page.html"
    main(["export-html", str(demo_run), str(out), "--max-points", "20000"])
    html = out.read_text()
    assert html.lstrip().lower().startswith("<!doctype html") and "__VISER_EMBED_DATA__" in html
    with pytest.raises(SystemExit) as ei:
        main(["export-html", str(tmp_path / "nothing"), str(tmp_path / "x.html")])
    assert ei.value.code == 2 and not (tmp_path / "x.html").exists()
    assert "nothing" in capfd.readouterr().err
