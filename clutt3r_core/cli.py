"""The ``clutt3r`` command line, generated with tyro from each command's typed signature.

Commands of the core are listed in ``_CORE_COMMANDS`` (``module:function``), imported
only when the CLI starts. Other packages add commands through the entry-point group
``clutt3r.commands`` (the viewer adds ``view`` and ``export-rerun``), so the core
never imports them by name.

Errors: a user error (any ``Clutt3rError``: a broken scene file, a missing run file, a
missing optional package) prints one line, ``clutt3r: error: <file>: <problem>``, and exits
with status 2, like tyro's own errors for bad arguments. ``--debug`` (anywhere on the
command line) or ``CLUTT3R_DEBUG=1`` prints the traceback too. Library calls keep
raising the typed errors; only this entry point turns them into a line.

``clutt3r segment`` starts before the others (issue 13, whole-command time): a plain
``SCENE --out RUN [--preset P]`` runs without tyro's parser, and ``main()`` called without an
argument list (the ``clutt3r`` script, ``python -m``) ends the process when the run is written,
without the interpreter's teardown (``_segment_without_parser``, ``_end_process``).
"""

from __future__ import annotations

import importlib
import os
import sys
from typing import Callable

__all__ = ["main", "available_commands"]

_CORE_COMMANDS: dict[str, str] = {
    "synth": "clutt3r_core.synth.cli:synth_command",
    "segment": "clutt3r_core.commands.segment:segment_command",
    "masks": "clutt3r_core.commands.masks:masks_command",
    "bench": "clutt3r_core.commands.bench:bench_command",
    "doctor": "clutt3r_core.commands.doctor:doctor_command",
    "grasp": "clutt3r_core.commands.grasp:grasp_command",
    "query": "clutt3r_core.commands.query:query_command",
    "update": "clutt3r_core.commands.update:update_command",
    "export-gt": "clutt3r_core.commands.export_gt:export_gt_command",
    "explain": "clutt3r_core.commands.explain:explain_command",
}


def _load(target: str) -> Callable | None:
    module, _, attr = target.partition(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError as e:
        if e.name and module.startswith(e.name):
            return None  # that command's module is not part of this installation
        raise


def _command_target(name: str) -> str | None:
    """``module:function`` of the command called ``name`` (a core one or an entry point), or None."""
    if name in _CORE_COMMANDS:
        return _CORE_COMMANDS[name]
    from importlib.metadata import entry_points  # 70 ms: only for a command of another package

    for ep in entry_points(group="clutt3r.commands"):
        if ep.name == name:
            return ep.value
    return None


def _single_command(args: list[str]) -> tuple[str, Callable] | None:
    """The command named by the first argument, imported alone, or None (no name there, or
    an unknown one: then the whole command table answers, with its list and tyro's error).

    Building the table imports every command's module, each with its own dependencies
    (evaluation, grasping, the viewer): about 0.5 s per process that ``clutt3r segment``
    does not need (issue 13). The one command's parser is the same tyro parser; only the
    usage line reads ``[OPTIONS]`` instead of ``[SEGMENT OPTIONS]``.
    """
    if not args or args[0].startswith("-"):
        return None
    target = _command_target(args[0])
    fn = _load(target) if target is not None else None
    return (args[0], fn) if fn is not None else None


def available_commands() -> dict[str, Callable]:
    cmds: dict[str, Callable] = {}
    for name, target in _CORE_COMMANDS.items():
        fn = _load(target)
        if fn is not None:
            cmds[name] = fn
    from importlib.metadata import entry_points

    for ep in entry_points(group="clutt3r.commands"):
        fn = _load(ep.value)
        if fn is not None:
            cmds[ep.name] = fn
    return cmds


DEBUG_FLAG = "--debug"
DEBUG_ENV = "CLUTT3R_DEBUG"
USER_ERROR_STATUS = 2
"""Exit status of a user error (tyro uses 2 for bad arguments, as argparse does)."""


def _debug_requested(args: list[str]) -> tuple[list[str], bool]:
    """(args without ``--debug``, whether a traceback was asked for by the flag or the variable)."""
    env = os.environ.get(DEBUG_ENV, "").strip().lower() not in ("", "0", "false", "no")
    rest = [a for a in args if a != DEBUG_FLAG]
    return rest, env or len(rest) != len(args)


def _quiet_third_party() -> None:
    """Keep OpenCV's own log lines off the terminal: every image failure becomes our error.

    Must run before cv2 is first imported (it reads the variable once); a value the user
    set is kept. libpng's own "libpng error" lines are avoided by checking PNG files
    before decoding them (``io.images``).
    """
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")


BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _one_blas_thread() -> None:
    """Run numpy's BLAS on one thread, unless the user set a thread count in the environment.

    Every BLAS product of the commands is small (N x 3 projections, RANSAC blocks of
    4000 x 100, mask-by-mask similarities), too small for OpenBLAS's worker threads to
    help: they only spin between calls. Measured on a hard 640x480 scene, ``clutt3r segment``
    used 1 s less CPU of about 4 (the k-d tree queries keep their own threads), with
    identical results (issue 13). The variable covers BLAS libraries loaded from here on
    (scipy's) and, through the environment, the processes a command starts;
    threadpoolctl sets numpy's, already loaded with the package.
    """
    if any(v in os.environ for v in BLAS_THREAD_VARIABLES):
        return
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    from threadpoolctl import threadpool_limits  # a core dependency (pyproject.toml), like pipeline.segment's

    threadpool_limits(1, user_api="blas")


def _segment_without_parser(args: list[str]) -> bool:
    """``clutt3r segment``'s start (issue 13, whole-command time): the plain command lines
    (``SCENE --out RUN [--preset P]``, ``commands.segment_run.plain_arguments``) run without
    importing tyro and building its parser (~0.14 s of CPU). Returns whether the command ran;
    False: tyro parses ``args`` as for any command. (Loading the scene on a thread while the
    command imports was measured and removed: docs/benchmark.md "Session 7".)"""
    from clutt3r_core.commands.segment_run import plain_arguments, run_segment

    plain = plain_arguments(args)
    if plain is None:
        return False
    from clutt3r_core.config import PRESETS, SegmentConfig

    scene, out, preset = plain
    run_segment(scene, out, PRESETS[preset] if preset else SegmentConfig())
    return True


def _end_process() -> None:
    """End a finished ``clutt3r segment`` process without the interpreter's teardown.

    Tearing down the ~440 modules and their objects took 40-70 ms of the command's ~2 s (issue
    13; measured from the command's return to the process's end, 0.06-0.09 s normally, 0.01-0.02 s
    this way) for a process that ends anyway. The atexit handlers still run and the standard
    streams are flushed; the run folder was written and fsynced file by file. Only when every
    thread but daemons has finished (a plugin's thread that has not is waited for, as Python would).
    """
    import atexit
    import threading

    if any(t is not threading.main_thread() and not t.daemon and t.is_alive() for t in threading.enumerate()):
        return
    if sys.getprofile() is not None or sys.gettrace() is not None:
        return  # a profiler (python -m cProfile) or coverage reports after main returns: let it
    atexit._run_exitfuncs()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):  # a closed or broken pipe: as at a normal exit, nothing to add
            pass
    os._exit(0)


def _fail(message: str) -> None:
    # one line, whatever the message holds: a terminal user and a log parser both want one
    line = " ".join(str(message).split())
    sys.stderr.write(f"clutt3r: error: {line}\n")
    sys.stderr.flush()


def main(argv: list[str] | None = None) -> None:
    args, debug = _debug_requested(list(sys.argv[1:] if argv is None else argv))
    _quiet_third_party()
    _one_blas_thread()
    from clutt3r_core.errors import Clutt3rError

    try:
        if args[:1] == ["segment"] and _segment_without_parser(args[1:]):
            if argv is None:  # the process's own command line: nothing runs after this
                _end_process()
            return
        import tyro

        one = _single_command(args)
        if one is not None:
            name, fn = one
            tyro.cli(fn, prog=f"clutt3r {name}", args=args[1:])
            return
        cmds = available_commands()
        tyro.extras.subcommand_cli_from_dict(
            cmds,
            prog="clutt3r",
            description="Clutt3R: zero-shot 3D instance segmentation of cluttered tabletops. "
            f"Errors print one line; add {DEBUG_FLAG} (or set {DEBUG_ENV}=1) for the traceback.",
            args=args,
            sort_subcommands=False,
        )
    except Clutt3rError as e:
        if debug:
            import traceback

            traceback.print_exc()
        _fail(str(e))
        sys.exit(USER_ERROR_STATUS)
    except OSError as e:
        # a path the user gave that cannot be read or written (permissions, full disk, a
        # file where a folder is expected): name it; an OSError without a path is a bug
        if e.filename is None:
            raise
        if debug:
            import traceback

            traceback.print_exc()
        _fail(f"{e.filename}: {e.strerror or e}")
        sys.exit(USER_ERROR_STATUS)
    except KeyboardInterrupt:
        if debug:
            raise
        _fail("interrupted")
        sys.exit(130)


if __name__ == "__main__":
    main()
