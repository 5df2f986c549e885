"""``clutt3r explain RUN --masks F:M F:M`` / ``--supervoxel K``: why two masks were not put
together, why a super-voxel went to its instance (``clutt3r_core.explain``).

Prints the explanation in words and numbers; with ``--json`` one JSON object per question
(the typed result's fields) on its own line.
"""

from __future__ import annotations

import json as _json
import math
from pathlib import Path

from tyro.conf import Positional

__all__ = ["explain_command", "parse_mask_ref"]


def parse_mask_ref(text: str) -> tuple[int, int] | int:
    """``"F:M"`` (frame, mask id) or a plain node index ``"N"``."""
    from clutt3r_core.errors import SceneError

    try:
        if ":" in text:
            f, m = text.split(":", 1)
            return int(f), int(m)
        return int(text)
    except ValueError:
        raise SceneError(f"--masks: {text!r} is not FRAME:MASK (e.g. 3:12) or a node index") from None


def _nan_to_none(x):
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: _nan_to_none(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_nan_to_none(v) for v in x]
    return x


def explain_command(
    run: Positional[Path],
    masks: tuple[str, ...] = (),
    supervoxel: int | None = None,
    json: bool = False,
) -> None:
    """Explain a grouping decision of a run: two masks (--masks F:M F:M) and/or a super-voxel.

    Args:
        run: run folder written by `clutt3r segment`.
        masks: two masks as FRAME:MASK (mask id in that frame's mask image) or node indices.
        supervoxel: a super-voxel index (the viewer's "Why here?" shows it for a clicked point).
        json: print each explanation as one JSON object (NaN as null) instead of text.
    """
    from clutt3r_core.errors import SceneError
    from clutt3r_core.explain import as_trace, explain_pair, explain_supervoxel
    from clutt3r_core.runs import missing_run_file

    if not masks and supervoxel is None:
        raise SceneError("nothing to explain: give --masks F:M F:M and/or --supervoxel K")
    if masks and len(masks) != 2:
        raise SceneError(f"--masks takes exactly two masks, got {len(masks)}")
    missing = missing_run_file(run, ("trace/trace.json", "trace/trace.npz"))
    if missing is not None:
        from clutt3r_core.errors import SceneFileError

        raise SceneFileError(missing, "missing: not a clutt3r run folder")
    trace = as_trace(run)
    results = []
    if masks:
        results.append(explain_pair(trace, parse_mask_ref(masks[0]), parse_mask_ref(masks[1])))
    if supervoxel is not None:
        results.append(explain_supervoxel(trace, supervoxel))
    for r in results:
        print(_json.dumps(_nan_to_none(r.to_json())) if json else r.text())
