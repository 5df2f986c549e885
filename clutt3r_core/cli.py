"""The ``clutt3r`` command line, generated with tyro from each command's typed signature.

Commands of the core are listed in ``_CORE_COMMANDS`` (``module:function``), imported
only when the CLI starts. Other packages add commands through the entry-point group
``clutt3r.commands`` (the viewer adds ``view`` and ``export-rerun``), so the core
never imports them by name.
"""

from __future__ import annotations

import importlib
import sys
from importlib.metadata import entry_points
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
}


def _load(target: str) -> Callable | None:
    module, _, attr = target.partition(":")
    try:
        return getattr(importlib.import_module(module), attr)
    except ModuleNotFoundError as e:
        if e.name and module.startswith(e.name):
            return None  # that command's module is not part of this installation
        raise


def available_commands() -> dict[str, Callable]:
    cmds: dict[str, Callable] = {}
    for name, target in _CORE_COMMANDS.items():
        fn = _load(target)
        if fn is not None:
            cmds[name] = fn
    for ep in entry_points(group="clutt3r.commands"):
        fn = _load(ep.value)
        if fn is not None:
            cmds[ep.name] = fn
    return cmds


def main(argv: list[str] | None = None) -> None:
    import tyro

    cmds = available_commands()
    tyro.extras.subcommand_cli_from_dict(
        cmds,
        prog="clutt3r",
        description="Clutt3R: zero-shot 3D instance segmentation of cluttered tabletops.",
        args=sys.argv[1:] if argv is None else argv,
        sort_subcommands=False,
    )


if __name__ == "__main__":
    main()
