"""clutt3r_viewer.edit helpers that need no browser."""

from __future__ import annotations

import shutil

import numpy as np

from clutt3r_core.annotations import Merge
from clutt3r_viewer.edit import instance_option, node_instance_now, node_supervoxels, open_annotations, option_id, status_text


def test_node_supervoxels_leave_out_support_and_match_the_highlight(tiny_data):
    d = tiny_data
    i = int(next(j for j in range(len(d.trace.nodes)) if d.trace.nodes.is_leaf[j] and d.node_instance[j] >= 0))
    sv = node_supervoxels(d, i)
    assert len(sv) and not d.seg.sv_support[sv].any()
    occ = np.flatnonzero(d.trace.occupancy[i] > 0)
    assert set(sv) == set(occ) - set(np.flatnonzero(d.seg.sv_support))


def test_options_status_and_node_instance_follow_the_corrections(tiny_data, tiny_run_dir, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    d = tiny_data
    with open_annotations(run, d.seg, author="t") as a:
        lab = a.current
        counts = lab.point_counts()
        assert option_id(instance_option(lab, 0, counts)) == 0 and option_id("none") == -1
        i = int(next(j for j in range(len(d.trace.nodes)) if d.trace.nodes.is_leaf[j] and d.node_instance[j] == 1))
        assert node_instance_now(d, lab, i) == 1
        assert "0 edits" in status_text(a)
        a.apply_op(Merge(into=0, other=1))
        assert node_instance_now(d, a.current, i) == 0
        assert "1 edit**" in status_text(a) and "checkpoint at entry 0" in status_text(a)
        a.save()
        assert "checkpoint up to date" in status_text(a)
        # a second viewer on the same run while this one holds the log: read-only, not an error
        b = open_annotations(run, d.seg)
        assert b.readonly and b.current.equals(a.current)


def test_viewer_refuses_a_correction_log_of_another_run(tiny_run_dir, tmp_path):
    import pytest

    import clutt3r_viewer
    from clutt3r_core.annotations import LOG_NAME, Annotations, Delete
    from clutt3r_core.errors import SceneFileError
    from tests.viewer.conftest import free_port

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    with Annotations.open(run) as a:
        a.apply_op(Delete(0))
    log = (run / LOG_NAME).read_bytes()
    (run / LOG_NAME).write_bytes(log.replace(b'"instances_sha256":"', b'"instances_sha256":"0', 1))
    port = free_port()
    with pytest.raises(SceneFileError, match="different run"):
        clutt3r_viewer.start(run, port=port)
    import socket

    with socket.socket() as s:  # the server of the failed start was stopped: its port is free again
        s.bind(("127.0.0.1", port))


def test_tabs_editing_at_once_serialise_through_the_one_writer_and_lose_nothing(tiny_run_dir, tmp_path):
    """Four 'tabs' (threads) fire selection edits built from what they saw, at once, through
    ViewerApp.edit_run: each edit is either in the log (and in every later state) or refused with
    a reason; the log replays to the live labels; nothing is applied twice or lost."""
    import threading

    import clutt3r_viewer
    from clutt3r_core.annotations import LOG_NAME, Annotations, apply
    from clutt3r_viewer.edit import selection_op
    from tests.viewer.conftest import free_port

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    app = clutt3r_viewer.start(run, port=free_port())
    try:
        ann = app.annotations
        sv = app.data.seg.sv_labels
        refused: list[str] = []
        done: list[bool] = []

        class FakeSession:
            def notify(self, title, body):
                refused.append(body)

        def tab(seed: int) -> None:
            rng = np.random.default_rng(seed)
            for _ in range(15):
                kind = ("new", "assign", "merge", "delete", "split")[int(rng.integers(0, 5))]
                sel = np.isin(sv, rng.integers(0, sv.max() + 1, 3))
                seen = ann.current  # what this tab showed when its user pressed the button
                alive = seen.alive
                target = int(rng.choice(alive)) if len(alive) else -1

                def action(a, kind=kind, sel=sel, target=target):
                    return a.apply_op(selection_op(kind, a.base, a.current, sel, target))

                done.append(app.edit_run(action, FakeSession()))

        threads = [threading.Thread(target=tab, args=(i,)) for i in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        assert len(done) == 60 and sum(done) + len(refused) == 60 and sum(done) > 20
        assert all(r for r in refused)  # every refusal says why
        assert ann.num_ops == sum(done)  # every accepted edit is one log entry, none more
        fresh = Annotations.open(run, readonly=True)
        assert len(fresh.ops) == sum(done) and fresh.current.equals(ann.current)
        assert apply(ann.base, fresh.ops).equals(ann.current)
        assert (run / LOG_NAME).is_file()
    finally:
        app.stop()


def test_selection_ops_and_progress_line(tiny_data, tiny_run_dir, tmp_path):
    import pytest

    from clutt3r_core.errors import SceneError
    from clutt3r_viewer.edit import progress_text, selection_op

    run = tmp_path / "run"
    shutil.copytree(tiny_run_dir, run)
    d = tiny_data
    with open_annotations(run, d.seg, author="t") as a:
        lab = a.current
        assert "0/" in progress_text(a) and "no edit yet" in progress_text(a)
        sel = (lab.instance == 0) | (lab.instance == 1)
        op = selection_op("merge", a.base, lab, sel)
        assert {op.into, op.other, *op.others} == {0, 1}
        a.apply_op(op)
        part = (a.current.instance == op.into) & (d.seg.sv_labels == d.seg.sv_labels[np.flatnonzero(sel)[0]])
        a.apply_op(selection_op("split", a.base, a.current, part | (a.current.instance < 0)))
        k = a.current.num_instances - 1
        assert np.array_equal(a.current.instance == k, part)  # only the instance's points moved
        a.apply_op(selection_op("delete", a.base, a.current, part))
        assert (a.current.instance[part] == -1).all()
        a.apply_op(selection_op("assign", a.base, a.current, part, target=op.into))
        assert (a.current.instance[part] == op.into).all()
        with pytest.raises(SceneError, match="select points"):
            selection_op("new", a.base, a.current, np.zeros(len(part), bool))
        with pytest.raises(SceneError, match="two instances"):
            selection_op("merge", a.base, a.current, part)
        assert "last save" in progress_text(a)
