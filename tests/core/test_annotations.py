"""clutt3r_core.annotations: op effects, undo / redo, log recovery, wrong-run rejection, SIGKILL mid-save."""

from __future__ import annotations

import io
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import textwrap
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from clutt3r_core.annotations import (
    LOG_NAME,
    SNAPSHOT_NAME,
    Annotations,
    BaseLabels,
    CorrectionLogWarning,
    Delete,
    Merge,
    Redo,
    Relabel,
    SetCategory,
    Split,
    Undo,
    active_edits,
    apply,
    op_from_json,
    op_to_json,
)
from clutt3r_core.errors import SceneError, SceneFileError

REPO = Path(__file__).resolve().parents[2]


def _npz(**arrays) -> bytes:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    return buf.getvalue()


def make_base(n: int = 40, k: int = 4, ks: int = 10, seed: int = 0) -> BaseLabels:
    """n points in ks super-voxels; instances are whole super-voxels (as the vote makes them)."""
    rng = np.random.default_rng(seed)
    sv = np.sort(rng.integers(0, ks, n)).astype(np.int32)
    sv[:ks] = np.arange(ks)  # every super-voxel has a point
    sv_inst = rng.integers(-1, k, ks)
    sv_inst[:k] = np.arange(k)  # every instance has a super-voxel
    return BaseLabels(sv_inst[sv].astype(np.int32), np.linspace(0.9, 0.5, k).astype(np.float32), sv)


def write_run(folder: Path, base: BaseLabels) -> Path:
    """A minimal run folder: the two files Annotations reads (no trace needed)."""
    folder.mkdir(parents=True, exist_ok=True)
    n = len(base.instance)
    (folder / "instances.npz").write_bytes(_npz(
        points=np.zeros((n, 3), np.float32), colors=np.zeros((n, 3), np.uint8),
        instance=base.instance, scores=base.scores))
    (folder / "cloud.npz").write_bytes(_npz(sv_labels=base.sv_labels, sv_support=np.zeros(base.num_supervoxels, bool)))
    return folder


@pytest.fixture
def base() -> BaseLabels:
    return make_base()


@pytest.fixture
def run(tmp_path, base) -> Path:
    return write_run(tmp_path / "run", base)


# -- op effects ----------------------------------------------------------------------


def test_each_op_changes_exactly_what_it_says(base):
    inst0 = base.instance
    lab = apply(base, [Merge(into=0, other=1)])
    assert not (lab.instance == 1).any() and lab.deleted[1] and not lab.deleted[0]
    assert np.array_equal(lab.instance == 0, (inst0 == 0) | (inst0 == 1))
    assert np.array_equal(lab.instance[(inst0 != 0) & (inst0 != 1)], inst0[(inst0 != 0) & (inst0 != 1)])

    lab = apply(base, [Delete(2)])
    assert np.array_equal(lab.instance, np.where(inst0 == 2, -1, inst0)) and lab.deleted[2]

    sv_of_2 = np.unique(base.sv_labels[inst0 == 2])
    lab = apply(base, [Split(supervoxels=sv_of_2[:1], source=2)])
    assert lab.num_instances == base.scores.size + 1 and lab.scores[-1] == 1.0 and lab.categories[-1] == ""
    moved = (base.sv_labels == sv_of_2[0]) & (inst0 == 2)
    assert np.array_equal(lab.instance == lab.num_instances - 1, moved)
    assert np.array_equal(lab.instance[~moved], inst0[~moved])

    lab = apply(base, [Relabel(target=-1, supervoxels=(0,), points=(len(inst0) - 1,))])
    changed = (base.sv_labels == 0) | (np.arange(len(inst0)) == len(inst0) - 1)
    assert (lab.instance[changed] == -1).all() and np.array_equal(lab.instance[~changed], inst0[~changed])

    lab = apply(base, [SetCategory(3, "red mug")])
    assert lab.categories == ("", "", "", "red mug") and np.array_equal(lab.instance, inst0)

    inst, scores, cats = apply(base, [Merge(0, 1), SetCategory(0, "box")]).compact()
    assert len(scores) == 3 and cats[0] == "box" and set(np.unique(inst)) <= {-1, 0, 1, 2}


def test_invalid_ops_are_errors_and_are_not_logged(run):
    with Annotations.open(run, author="t") as a:
        a.apply_op(Delete(1))
        for bad in (Merge(0, 1), Delete(1), SetCategory(9, "x"), Relabel(7, points=(0,)),
                    Relabel(0, supervoxels=(99,)), Split(points=(10_000,))):
            with pytest.raises(SceneError):
                a.apply_op(bad)
        with pytest.raises(SceneError):
            Merge(2, 2)
        assert a.num_ops == 1
    assert len(Annotations.open(run, readonly=True).ops) == 1


def test_ops_round_trip_through_json():
    ops = [Relabel(1, (1, 2), (3,), "a", 1.5), Merge(0, 1, "b", 2.0), Split((4,), (), 2, 0.7, "c", 3.0),
           SetCategory(1, "ünïcode \"q\"\n", "d", 4.0), Delete(0, "e", 5.0), Undo(3, "f", 6.0), Redo(3, "g", 7.0)]
    for op in ops:
        assert op_from_json(json.loads(json.dumps(op_to_json(op)))) == op


# -- undo / redo ---------------------------------------------------------------------


def test_undo_redo_and_a_new_edit_clears_redo(run, base):
    with Annotations.open(run, author="t") as a:
        assert not a.can_undo and not a.can_redo
        a.apply_op(Merge(0, 1))
        a.apply_op(SetCategory(0, "mug"))
        a.undo()
        assert a.current.categories[0] == "" and a.can_redo and a.can_undo
        a.undo()
        assert np.array_equal(a.current.instance, base.instance) and not a.can_undo
        a.redo()
        assert a.current.deleted[1] and a.can_redo
        a.apply_op(Delete(2))  # new edit after undo: redo stack cleared
        assert not a.can_redo
        with pytest.raises(SceneError):
            a.redo()
        kinds = [type(e.op).__name__ for e in a.history()]
        assert kinds == ["Merge", "SetCategory", "Undo", "Undo", "Redo", "Delete"]
        assert [e.index for e in a.history() if e.active] == [0, 5]
        live = a.current
    b = Annotations.open(run, readonly=True)
    assert b.current.equals(live) and b.num_edits == 2


def test_an_inconsistent_undo_in_a_log_is_an_error():
    with pytest.raises(SceneError, match="entry 2"):
        active_edits([Delete(0), Delete(1), Undo(0)])


def _reference(base: BaseLabels, edits) -> tuple[np.ndarray, list[str], list[bool]]:
    """Per-point loop model of the edits (independent of the vectorised apply)."""
    inst = [int(x) for x in base.instance]
    cats = [""] * len(base.scores)
    deleted = [False] * len(base.scores)
    svl = [int(x) for x in base.sv_labels]
    for op in edits:
        if isinstance(op, Relabel):
            for p in range(len(inst)):
                if svl[p] in op.supervoxels or p in op.points:
                    inst[p] = op.target
        elif isinstance(op, Merge):
            inst = [op.into if x == op.other else x for x in inst]
            deleted[op.other] = True
        elif isinstance(op, Split):
            k = len(cats)
            for p in range(len(inst)):
                if (svl[p] in op.supervoxels or p in op.points) and (op.source is None or inst[p] == op.source):
                    inst[p] = k
            cats.append("")
            deleted.append(False)
        elif isinstance(op, SetCategory):
            cats[op.instance] = op.text
        elif isinstance(op, Delete):
            inst = [-1 if x == op.instance else x for x in inst]
            deleted[op.instance] = True
    return np.array(inst), cats, deleted


_ids = st.integers(-1, 6)
_edit = st.one_of(
    st.builds(Relabel, _ids, st.lists(st.integers(0, 9), max_size=3).map(tuple),
              st.lists(st.integers(0, 39), max_size=3).map(tuple)),
    st.tuples(st.integers(0, 6), st.integers(0, 6)).filter(lambda t: t[0] != t[1]).map(lambda t: Merge(*t)),
    st.builds(Split, st.lists(st.integers(0, 9), min_size=1, max_size=3).map(tuple), st.just(()),
              st.one_of(st.none(), _ids)),
    st.builds(SetCategory, st.integers(0, 6), st.text(max_size=5)),
    st.builds(Delete, st.integers(0, 6)),
)
_action = st.one_of(_edit, st.just("undo"), st.just("redo"))


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(actions=st.lists(_action, max_size=14))
def test_property_any_edit_undo_redo_sequence_replays_to_the_in_memory_state(actions):
    base = make_base()
    with tempfile.TemporaryDirectory() as d:
        run = write_run(Path(d) / "run", base)
        a = Annotations.open(run, author="prop")
        stack: list = []  # model: edits in effect
        redo: list = []
        for step, act in enumerate(actions):
            if len(actions) % 3 == 0 and step == len(actions) // 2:
                a.save()  # a checkpoint behind the log: reopening replays the tail (undos of older edits too)
            if act == "undo":
                assert a.can_undo == bool(stack)
                if stack:
                    a.undo()
                    redo.append(stack.pop())
            elif act == "redo":
                assert a.can_redo == bool(redo)
                if redo:
                    a.redo()
                    stack.append(redo.pop())
            else:
                try:
                    a.apply_op(act)
                except SceneError:
                    continue  # invalid on the current state: rejected, nothing logged
                stack.append(act)
                redo.clear()
        live = a.current
        inst, cats, deleted = _reference(base, stack)
        assert np.array_equal(live.instance, inst) and list(live.categories) == cats
        assert live.deleted.tolist() == deleted
        if len(actions) % 2:
            a.save()  # half the examples reopen from the snapshot, half replay
        a.close()
        fresh = Annotations.open(run, readonly=True)  # a fresh state: log (+ snapshot) from disk
        assert fresh.current.equals(live)
        assert fresh.ops == a.ops
        assert apply(base, fresh.ops).equals(live)
        assert (fresh.can_undo, fresh.can_redo) == (bool(stack), bool(redo))


# -- the log on disk -----------------------------------------------------------------


def test_log_is_appended_at_once_and_snapshot_is_used_only_when_it_matches(run):
    a = Annotations.open(run, author="ann")
    assert not (run / LOG_NAME).exists()  # opening creates nothing
    a.apply_op(Delete(0))
    lines = (run / LOG_NAME).read_text().splitlines()
    assert len(lines) == 2 and json.loads(lines[1])["op"] == "delete" and json.loads(lines[1])["author"] == "ann"
    assert json.loads(lines[0])["format"] == "clutt3r-corrections"
    assert not a.saved
    a.save()
    assert a.saved and (run / SNAPSHOT_NAME).is_file()
    a.apply_op(SetCategory(1, "x"))
    assert not a.saved
    a.close()
    # the snapshot reflects 1 op, the log has 2: replay gives the category
    assert Annotations.open(run, readonly=True).current.categories[1] == "x"
    # a snapshot that matches but lies (hand-edited log of the same length) is not trusted
    b = Annotations.open(run)
    b.save()
    b.close()
    raw = (run / LOG_NAME).read_bytes().replace(b'"text":"x"', b'"text":"y"')
    (run / LOG_NAME).write_bytes(raw)
    assert Annotations.open(run, readonly=True).current.categories[1] == "y"
    assert (run / "instances.npz").read_bytes() == (run.parent / "run" / "instances.npz").read_bytes()


def test_original_instances_file_is_never_touched(run):
    before = (run / "instances.npz").read_bytes()
    with Annotations.open(run) as a:
        a.apply_op(Delete(0))
        a.save()
    assert (run / "instances.npz").read_bytes() == before


def test_torn_last_line_is_ignored_with_a_warning_and_cut_before_appending(run):
    with Annotations.open(run) as a:
        a.apply_op(Delete(0))
        a.apply_op(SetCategory(1, "mug"))
    log = run / LOG_NAME
    good = log.read_bytes()
    log.write_bytes(good + b'{"op":"delete","instance":2,"au')  # crash mid-append
    with pytest.warns(CorrectionLogWarning, match=r"ops\.jsonl: line 4"):
        r = Annotations.open(run, readonly=True)
    assert len(r.ops) == 2 and r.current.categories[1] == "mug"
    assert log.read_bytes().endswith(b'"au')  # read-only: the file is left as it is
    with pytest.warns(CorrectionLogWarning):
        w = Annotations.open(run)
    assert log.read_bytes() == good  # cut back to the last complete line, bytes kept aside
    assert (run / "corrections" / "ops.jsonl.torn").read_bytes().startswith(b'{"op":"delete"')
    w.apply_op(Delete(3))
    w.close()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert len(Annotations.open(run, readonly=True).ops) == 3
    # a complete but garbled last line (e.g. zeros after a power cut) is also a torn line
    log.write_bytes(log.read_bytes() + b"\x00" * 20 + b"\n")
    with pytest.warns(CorrectionLogWarning, match="line 5"):
        assert len(Annotations.open(run, readonly=True).ops) == 3


def test_corrupt_middle_line_is_an_error_naming_file_and_line(run):
    with Annotations.open(run) as a:
        a.apply_op(Delete(0))
        a.apply_op(Delete(1))
        a.apply_op(Delete(2))
    log = run / LOG_NAME
    lines = log.read_bytes().split(b"\n")
    lines[2] = lines[2][:10]
    log.write_bytes(b"\n".join(lines))
    with pytest.raises(SceneFileError, match=r"ops\.jsonl: line 3: corrupt"):
        Annotations.open(run, readonly=True)


def test_log_of_another_run_is_rejected(tmp_path, run):
    with Annotations.open(run) as a:
        a.apply_op(Delete(0))
    other = write_run(tmp_path / "other", make_base(seed=1))
    (other / "corrections").mkdir()
    (other / LOG_NAME).write_bytes((run / LOG_NAME).read_bytes())
    with pytest.raises(SceneFileError, match="different run") as e:
        Annotations.open(other)
    assert e.value.path == other / LOG_NAME


def test_a_second_writer_is_refused_while_the_first_holds_the_log(run):
    a = Annotations.open(run)
    a.apply_op(Delete(0))
    with pytest.raises(SceneFileError, match="another process"):
        Annotations.open(run)
    assert Annotations.open(run, readonly=True).num_ops == 1  # readers are fine
    a.close()
    Annotations.open(run).close()


def test_corrections_of_a_real_segmented_run(tmp_path):
    from clutt3r_core.pipeline import load_run, save_run, segment
    from clutt3r_core.synth import SynthConfig, generate_scene

    scene = generate_scene(SynthConfig(seed=0, preset="easy", views=3, width=320, height=240, n_objects=3),
                           progress=False)
    seg = segment(scene)
    assert seg.num_instances >= 2
    save_run(seg, tmp_path / "run")
    with Annotations.open(tmp_path / "run", segmentation=seg, author="t") as a:
        a.apply_op(Merge(0, 1))
        node_sv = np.flatnonzero(seg.trace.occupancy[seg.instance_nodes(0)[0]] > 0)
        a.apply_op(Split(supervoxels=node_sv, source=0))
        a.save()
        live = a.current
    re = Annotations.open(tmp_path / "run", segmentation=load_run(tmp_path / "run"), readonly=True)
    assert re.current.equals(live) and live.num_instances == seg.num_instances + 1
    assert (live.instance == 1).sum() == 0 and (live.instance == seg.num_instances).any()


# -- SIGKILL mid-save ----------------------------------------------------------------

_WRITER = textwrap.dedent("""
    import random, sys
    import numpy as np
    from clutt3r_core.annotations import Annotations, Relabel, SetCategory, Split, Delete, Merge
    from clutt3r_core.errors import SceneError
    run, seed = sys.argv[1], int(sys.argv[2])
    rng = random.Random(seed)
    a = Annotations.open(run, author=f"writer{seed}")
    n, ks = len(a.base.instance), a.base.num_supervoxels
    print("ready", a.num_ops, flush=True)
    while True:
        r = rng.random()
        cur = a.current
        alive = [int(k) for k in cur.alive]
        try:
            if r < 0.15 and a.can_undo:
                a.undo()
            elif r < 0.25 and a.can_redo:
                a.redo()
            elif r < 0.35:
                lo = rng.randrange(n)
                a.apply_op(Relabel(rng.choice(alive + [-1]), points=range(lo, min(n, lo + 40000))))  # a long line
            elif r < 0.55:
                a.apply_op(SetCategory(rng.choice(alive), "cat%d" % rng.randrange(1000)))
            elif r < 0.7:
                a.apply_op(Split(supervoxels=rng.sample(range(ks), 3)))
            elif r < 0.8 and len(alive) > 3:
                a.apply_op(Merge(*rng.sample(alive, 2)))
            elif len(alive) > 3:
                a.apply_op(Delete(rng.choice(alive)))
            else:
                continue
        except SceneError:
            continue
        print("ack", a.num_ops - 1, type(a.ops[-1]).__name__, a.ops[-1].time, flush=True)  # after fsync
        if rng.random() < 0.3:
            a.save()
            print("saved", a.num_ops, flush=True)
""")


@pytest.mark.slow
def test_sigkill_at_random_moments_loses_no_acknowledged_op_and_no_snapshot(tmp_path):
    base = make_base(n=120_000, k=12, ks=3000, seed=3)
    run = write_run(tmp_path / "run", base)
    rng = random.Random(1234)
    kills, deadline = 0, time.time() + 40.0
    acked: dict[int, tuple[str, float]] = {}
    snapshot_seen = set()
    torn = 0
    env = dict(os.environ, PYTHONPATH=str(REPO))
    while kills < 8 and time.time() < deadline:
        p = subprocess.Popen([sys.executable, "-c", _WRITER, str(run), str(kills)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True, env=env, cwd=REPO)
        line = p.stdout.readline()
        assert line.startswith("ready"), p.stderr.read()
        time.sleep(rng.uniform(0.05, 0.8))
        os.kill(p.pid, signal.SIGKILL)
        out, err = p.communicate(timeout=10)
        assert p.returncode == -signal.SIGKILL, err
        kills += 1
        # only whole lines are acknowledgements: the kill can land while the writer prints one, and
        # a torn last line (no newline; an IndexError in one clean-clone run) was never received as an ack
        for ln in out.split("\n")[:-1]:
            parts = ln.split()
            if parts and parts[0] == "ack":
                acked[int(parts[1])] = (parts[2], float(parts[3]))
        # the snapshot is always a complete file: old or new
        snap = run / SNAPSHOT_NAME
        if snap.exists():
            with np.load(snap) as z:
                n_snap = int(z["num_ops"])
                snap_inst = z["instance"].copy()
            snapshot_seen.add(n_snap)
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always")
            a = Annotations.open(run)  # writable: recovers the tail for the next writer
        torn += sum(issubclass(x.category, CorrectionLogWarning) for x in w)
        assert len(a.ops) >= len(acked)
        for i, (kind, t) in acked.items():
            assert type(a.ops[i]).__name__ == kind and a.ops[i].time == t, f"acknowledged op {i} lost"
        assert a.current.equals(apply(base, a.ops))
        if snap.exists():
            assert n_snap <= len(a.ops)
            assert np.array_equal(snap_inst, apply(base, a.ops[:n_snap]).instance)
        assert not list((run / "corrections").glob(".*.tmp"))  # stale temp files were cleaned
        a.close()
    assert kills >= 5, f"only {kills} kills in the time limit"
    assert len(acked) > 10 and snapshot_seen
    print(f"\n{kills} kills, {len(acked)} acknowledged ops kept, {len(snapshot_seen)} snapshot versions, "
          f"{torn} torn tails recovered")


# -- constant-time undo, checkpoints, compact selections (issue 12) ---------------------


def test_undo_after_reopening_from_an_old_checkpoint_uses_its_stored_inverses(run, base):
    with Annotations.open(run, author="t") as a:
        a.apply_op(Split(supervoxels=(0, 1)))
        a.apply_op(Merge(0, 2, others=(3,)))
        a.apply_op(SetCategory(0, "bowl"))
        a.save()  # checkpoint at 3 entries
        a.undo()  # tail: undo of an edit the checkpoint covers
        a.apply_op(Relabel(-1, points=tuple(range(5, 30))))
        live = a.current
    b = Annotations.open(run, author="t")
    assert b.saved_ops == 3 and b.current.equals(live)
    b.undo()
    b.undo()  # reverts the Merge using the inverse read from the checkpoint, not a replay
    assert b.current.equals(apply(base, [Split(supervoxels=(0, 1))]))
    assert b.current.equals(apply(base, b.ops))
    b.close()


def test_a_snapshot_without_inverses_older_format_is_replayed_not_trusted(run, base):
    with Annotations.open(run, author="t") as a:
        a.apply_op(Delete(1))
        a.save()
    p = run / SNAPSHOT_NAME
    with np.load(p) as z:
        arrays = {k: z[k] for k in z.files if not k.startswith("inv_")}
    p.write_bytes(_npz(**arrays))
    b = Annotations.open(run)
    assert b.saved_ops == 0 and b.current.equals(apply(base, [Delete(1)]))
    b.undo()
    assert b.current.equals(apply(base, []))
    b.close()


def test_long_point_selections_are_stored_as_runs_and_round_trip():
    pts = tuple(range(1000, 50_000)) + tuple(range(60_000, 60_010))
    op = Relabel(2, points=pts, author="a", time=1.0)
    d = op_to_json(op)
    assert d["points"] == {"ranges": [1000, 50_000, 60_000, 60_010]}
    assert len(json.dumps(d)) < 200 and op_from_json(json.loads(json.dumps(d))) == op
    scattered = Relabel(2, points=(5, 3, 9), author="a", time=1.0)  # unsorted: kept literally
    assert op_to_json(scattered)["points"] == [5, 3, 9]
    with pytest.raises(SceneError):
        op_from_json({"op": "relabel", "target": 1, "points": {"ranges": [5, 2]}})


def test_merge_of_several_instances_is_one_entry(base):
    lab = apply(base, [Merge(0, 1, others=(2, 3))])
    assert lab.deleted[1:4].all() and set(np.unique(lab.instance)) <= {-1, 0}
    assert (lab.instance == 0).sum() == (base.instance >= 0).sum()
    with pytest.raises(SceneError):
        Merge(0, 1, others=(0,))
    with pytest.raises(SceneError):
        Merge(0, 1, others=(1,))
    assert "others" not in op_to_json(Merge(0, 1))  # older logs and readers: unchanged form


def test_selection_fields_name_exactly_the_mask(base):
    from clutt3r_core.corrections import selection_fields

    rng = np.random.default_rng(3)
    for _ in range(20):
        mask = rng.random(len(base.instance)) < rng.random()
        mask |= base.sv_labels == rng.integers(0, base.num_supervoxels)  # one whole super-voxel
        sv, pts = selection_fields(base, mask)
        again = np.isin(base.sv_labels, sv)
        again[list(pts)] = True
        assert np.array_equal(again, mask) and len(sv) >= 1
        assert not np.isin(base.sv_labels[list(pts)], sv).any()  # no point named twice


def test_category_suggestions_most_used_first_then_extra(base):
    from clutt3r_core.corrections import category_suggestions

    lab = apply(base, [SetCategory(0, "mug"), SetCategory(1, "bowl"), SetCategory(2, "mug")])
    assert category_suggestions(lab) == ("mug", "bowl")
    assert category_suggestions(lab, "b", extra=("banana", "mug")) == ("bowl", "banana")
    lab = apply(base, [SetCategory(0, "mug"), Delete(0)])
    assert category_suggestions(lab) == ()  # deleted instances do not suggest


@settings(max_examples=80, deadline=None)
@given(actions=st.lists(_edit, min_size=1, max_size=10), seed=st.integers(0, 5))
def test_property_sparse_apply_and_revert_match_the_replay(actions, seed):
    """correction_undo.apply_edit (O(selection)) == corrections._apply_edit (the replay's),
    and revert(apply_edit(x)) == x, for any valid edit on any reachable state."""
    from clutt3r_core.correction_undo import apply_edit, revert
    from clutt3r_core.corrections import _apply_edit, _initial

    base = make_base(seed=seed)
    lab = _initial(base)
    for op in actions:
        try:
            ref = _apply_edit(base, lab, op)
        except SceneError:
            with pytest.raises(SceneError):
                apply_edit(base, lab, op)
            continue
        new, inv = apply_edit(base, lab, op)
        assert new.equals(ref)
        assert revert(new, inv).equals(lab)
        lab = new


def test_undo_deeper_than_the_checkpoint_keeps_rebuilds_once(run, base, monkeypatch):
    import clutt3r_core.annotations as mod

    monkeypatch.setattr(mod, "CHECKPOINT_UNDO_DEPTH", 2)
    ops = [SetCategory(0, "a"), Split(supervoxels=(0,)), Merge(1, 2), SetCategory(1, "b"), Delete(3)]
    with Annotations.open(run, author="t") as a:
        for op in ops:
            a.apply_op(op)
        a.save()
    with np.load(run / SNAPSHOT_NAME) as z:
        assert z["inv_edit"].tolist() == [3, 4]  # the top two only
    b = Annotations.open(run, author="t")
    assert b.saved_ops == 5 and set(b._inverse) == {3, 4}
    for k in range(5, 0, -1):  # undo everything: the third undo rebuilds, the rest are O(1)
        b.undo()
        assert b.current.equals(apply(base, ops[: k - 1]))
    for k in range(1, 6):
        b.redo()
        assert b.current.equals(apply(base, ops[:k]))
    assert apply(base, b.ops).equals(b.current)
    b.close()
