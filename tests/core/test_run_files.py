"""The correction log's path has one source (``run_files.CORRECTION_LOG``) that the update's
start-up reads without loading the correction modules that write the log."""

from __future__ import annotations

import subprocess
import sys


def test_one_log_name_for_the_writer_and_the_update():
    from clutt3r_core import annotations, run_files
    from clutt3r_core.update import run_labels

    assert annotations.LOG_NAME is run_labels.LOG_NAME is run_files.CORRECTION_LOG == "corrections/ops.jsonl"


def test_the_update_labels_module_does_not_load_the_correction_modules():
    code = ("import sys, clutt3r_core.update.run_labels, clutt3r_core.commands.update; "
            "print(sorted(m for m in sys.modules if m in ('clutt3r_core.annotations', 'clutt3r_core.corrections', "
            "'clutt3r_core.correction_undo')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]", out
