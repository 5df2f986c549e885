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
        assert "1 edit**" in status_text(a) and "snapshot pending" in status_text(a)
        a.save()
        assert "saved" in status_text(a)
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
