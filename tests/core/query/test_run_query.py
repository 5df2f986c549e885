"""RunQuery and ``clutt3r query`` on a tiny generated run: evidence cache, JSON output, target
points, bad input. The backend is ``_fake.FakeGrounder`` (wiring, not language quality); the real
backend is exercised in tests/core/language/test_lite.py."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clutt3r_core.commands.query import query_command
from clutt3r_core.errors import Clutt3rError, SceneFileError
from clutt3r_core.query import RunQuery
from clutt3r_core.query.evidence import CACHE_NAME
from clutt3r_core.runs import save_run
from clutt3r_core.synth import write_synth_scene
from tests.core._tiny_run import tiny_scene, tiny_segmentation
from tests.core.query._fake import FakeGrounder, copy_run, fake_ground_registered


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    root = tmp_path_factory.mktemp("q")
    scene_dir = write_synth_scene(tiny_scene(), root / "scene", contact_sheet=False)
    run = save_run(tiny_segmentation(), root / "run", scene_root=scene_dir)
    return root, run


@pytest.fixture
def run_copy(tiny_run, tmp_path):
    root, run = tiny_run
    return copy_run(run, root, tmp_path / "run")


@pytest.fixture
def fake_registered():
    with fake_ground_registered():
        yield


def test_evidence_is_cached_and_reused(run_copy):
    g = FakeGrounder()
    rq = RunQuery.open(run_copy, grounder=g)
    assert g.calls > 0 and (run_copy / CACHE_NAME).is_file()
    seg = rq.seg
    assert rq.instances.num_instances == seg.num_instances
    assert len(rq.evidence.nodes) == len({n for k in range(seg.num_instances) for n in seg.instance_nodes(k)})
    g2 = FakeGrounder()
    rq2 = RunQuery.open(run_copy, grounder=g2)
    assert g2.calls == 0  # from the cache
    np.testing.assert_allclose(rq2.instances.grounding, rq.instances.grounding, atol=1e-6)
    g3 = FakeGrounder(version="2")  # another backend version: recomputed, never reused
    RunQuery.open(run_copy, grounder=g3)
    assert g3.calls > 0


def test_colour_query_picks_the_instance_of_that_colour(run_copy):
    rq = RunQuery.open(run_copy, grounder=FakeGrounder())
    from clutt3r_core.language.colors import COLOR_WORDS

    for word in ("orange", "blue"):  # the tiny scene: power drill (teal-blue), mug (blue), clamp (orange)
        res = rq.query(word)  # a colour word only: no name term, the colour term decides
        share = rq.instances.colors[:, COLOR_WORDS.index(word)]
        assert share.max() > 0.2
        # the winner has the largest share of that colour among the instances
        assert share[res.target] == pytest.approx(share.max())


def test_cli_json_and_target_points(run_copy, fake_registered, capsys):
    query_command(run_copy, "the red thing", json=True, backend="fake-ground")
    last = capsys.readouterr().out.strip().splitlines()[-1]
    d = json.loads(last)
    assert set(d) == {"query", "ranking", "target", "confident", "time_s"}
    seg = RunQuery.open(run_copy, grounder=FakeGrounder()).seg
    assert sorted(r["instance"] for r in d["ranking"]) == list(range(seg.num_instances))
    assert d["target"] == d["ranking"][0]["instance"]
    with np.load(run_copy / "query_target.npz") as z:
        assert int(z["instance"]) == d["target"]
        np.testing.assert_array_equal(z["points"], seg.points[seg.instance == d["target"]])
    assert (run_copy / "query_target.ply").is_file()


def test_cli_human_output(run_copy, fake_registered, capsys):
    query_command(run_copy, "blue thing", top=2, backend="fake-ground")
    out = capsys.readouterr().out
    assert "-> instance" in out and "1. instance" in out and "3. instance" not in out


@pytest.mark.parametrize("text", ["", "   "])
def test_cli_empty_query(run_copy, text):
    # query_command lets typed errors reach the CLI (one line, status 2: tests/core/robustness)
    with pytest.raises(Clutt3rError, match="empty query"):
        query_command(run_copy, text)


def test_cli_unknown_run_folder(tmp_path):
    with pytest.raises(Clutt3rError, match="no such run folder"):
        query_command(tmp_path / "nope", "mug")
    (tmp_path / "empty").mkdir()
    with pytest.raises(Clutt3rError, match="not a clutt3r run folder"):
        query_command(tmp_path / "empty", "mug")


def test_run_without_scene_and_without_cache(run_copy, fake_registered):
    info = json.loads((run_copy / "run.json").read_text())
    info["scene"] = None
    (run_copy / "run.json").write_text(json.dumps(info))
    with pytest.raises(Clutt3rError, match="pass --scene"):
        query_command(run_copy, "mug", backend="fake-ground")
    with pytest.raises(SceneFileError):
        RunQuery.open(run_copy, grounder=FakeGrounder())


def test_stale_cache_of_another_run_is_recomputed(run_copy):
    RunQuery.open(run_copy, grounder=FakeGrounder())
    (run_copy / "instances.npz").write_bytes((run_copy / "instances.npz").read_bytes() + b"")  # same bytes
    g = FakeGrounder()
    RunQuery.open(run_copy, grounder=g)
    assert g.calls == 0
    # a re-segmented run (different trace) must not reuse the cached evidence
    tj = run_copy / "trace" / "trace.json"
    tj.write_text(tj.read_text() + " ")
    g = FakeGrounder()
    RunQuery.open(run_copy, grounder=g)
    assert g.calls > 0


def test_stale_colours_and_labels_refresh_without_the_network(run_copy):
    from clutt3r_core.language.colors import COLOR_VERSION
    from clutt3r_core.query.evidence import load_node_evidence, run_cache_key, save_node_evidence

    from dataclasses import replace

    rq = RunQuery.open(run_copy, grounder=FakeGrounder())
    key = run_cache_key(run_copy, "fake-ground", "1")
    ev = load_node_evidence(run_copy / CACHE_NAME, key)
    save_node_evidence(replace(ev, colors=ev.colors * 0, color_version="old", labels=("x",) * 3),
                       run_copy / CACHE_NAME, key)
    g = FakeGrounder()
    rq2 = RunQuery.open(run_copy, grounder=g)
    assert g.calls == 0
    assert rq2.evidence.color_version == COLOR_VERSION and rq2.evidence.labels == g.labels
    np.testing.assert_allclose(rq2.evidence.colors, rq.evidence.colors, atol=1e-6)


def test_no_target_removes_a_stale_target_file(run_copy, fake_registered):
    from types import SimpleNamespace

    from clutt3r_core.commands.query import write_target

    query_command(run_copy, "the red thing", backend="fake-ground")
    assert (run_copy / "query_target.npz").is_file()
    assert write_target(run_copy, None, SimpleNamespace(target=None)) is None
    assert not (run_copy / "query_target.npz").exists() and not (run_copy / "query_target.ply").exists()
