"""Run warnings: what a run says when its input was degraded, instead of degrading silently.

A ``RunWarning`` is one typed, one-line notice about one frame (or the whole scene). The
loaders put theirs on ``Scene.warnings`` (e.g. a frame taken as post-interaction because
its depth file is missing), ``pipeline.segment`` adds the view checks below, the run keeps
them all in ``Segmentation.warnings`` and ``run.json`` (``runs.read_run_info(run).warnings``),
and ``clutt3r segment`` prints each on the terminal.

The view checks, on the fused cloud of the initial views:

* ``no-usable-depth`` (an error, ``SceneError``): no view fed a single voxel;
* ``view-dropped``: a view fed no voxel (every depth pixel a hole or out of range);
* ``depth-invalid``: more than ``DEPTH_INVALID_FRACTION`` of a view's pixels are holes or
  out of range;
* ``view-isolated``: less than ``MIN_VIEW_OVERLAP`` of a view's voxels were also fed by
  another view, so its masks have nothing to be matched with across views;
* ``view-no-masks``: a view has no mask candidate, so it adds no 2D evidence.

This module imports nothing of the scene model at run time, so ``scene.py`` can hold
``RunWarning`` values without an import cycle.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from clutt3r_core.errors import SceneError

if TYPE_CHECKING:  # only for annotations: scene.py imports this module
    from clutt3r_core.pointcloud import FusedCloud, PointCloudConfig
    from clutt3r_core.scene import View

__all__ = [
    "RunWarning",
    "WARNING_CODES",
    "DEPTH_INVALID_FRACTION",
    "MIN_VIEW_OVERLAP",
    "view_warnings",
    "check_usable_depth",
    "invalid_depth_fraction",
]

WARNING_CODES: dict[str, str] = {
    "frame-demoted": "a frame was taken as post-interaction because it has no depth file",
    "view-dropped": "a view fed no point of the 3D cloud (no usable depth)",
    "depth-invalid": "most of a view's depth is holes or out of range",
    "view-isolated": "a view sees almost nothing that another view sees",
    "view-no-masks": "a view has no mask candidate",
    "updates-unreadable": "the run's scene updates could not be read; it is shown without them",
}
"""Every warning code and what it means (docs/robustness.md lists them too)."""

DEPTH_INVALID_FRACTION = 0.5
"""A view whose invalid depth pixels (holes, or outside [min_depth, max_depth]) exceed this
fraction is warned about (ours: "most of the view"; measured 0 % on both real samples,
<= 0.7 % on a generated easy scene and 3.4-9.6 % on a generated hard scene with the
RealSense-like noise model (``clutt3r synth --preset hard --seed 1 --depth-noise realsense``),
so the warning fires only on a view that is really broken: a lens cap, a wrong depth
scale, a camera pointed past the table)."""

MIN_VIEW_OVERLAP = 0.05
"""A view is isolated when fewer than this fraction of the voxels it fed were also fed by
another view (ours: per view, 40-80 % on sample_seq1, 62-88 % on sample_seq4 and 94-99 %
on generated scenes; 5 %, eight times below the lowest real view, still flags a camera
pointed elsewhere that shares only a few stray voxels with the others)."""


@dataclass(frozen=True)
class RunWarning:
    """One degradation of a run's input, said in one line.

    Attributes:
        code: one of ``WARNING_CODES``.
        message: one line in our words, naming the frame / file and what it means for the run.
        frame: the frame it is about, None when it is about the whole scene.
        view: the view's name (its image file), "" when none.
    """

    code: str
    message: str
    frame: int | None = None
    view: str = ""

    def __post_init__(self) -> None:
        if self.code not in WARNING_CODES:
            raise SceneError(f"unknown run warning code {self.code!r} (known: {', '.join(WARNING_CODES)})")
        if not isinstance(self.message, str) or "\n" in self.message:
            raise SceneError("a run warning message must be one line of text")
        if self.frame is not None:
            object.__setattr__(self, "frame", int(self.frame))

    def to_json(self) -> dict:
        return {"code": self.code, "frame": self.frame, "view": self.view, "message": self.message}

    @staticmethod
    def from_json(d: object) -> RunWarning:
        """The inverse of ``to_json``; ``SceneError`` when ``d`` is not one."""
        if not isinstance(d, Mapping):
            raise SceneError(f"a run warning must be an object, got {d!r}")
        code, msg, frame, view = d.get("code"), d.get("message"), d.get("frame"), d.get("view", "")
        if not isinstance(code, str) or not isinstance(msg, str) or not isinstance(view, str):
            raise SceneError(f"a run warning needs string 'code' and 'message', got {dict(d)!r}")
        if frame is not None and (isinstance(frame, bool) or not isinstance(frame, int)):
            raise SceneError(f"a run warning's 'frame' must be an integer or null, got {frame!r}")
        return RunWarning(code=code, message=msg, frame=frame, view=view)

    def __str__(self) -> str:
        return self.message


def _label(v: View) -> str:
    return f"frame {v.frame} ({v.name})" if v.name else f"frame {v.frame}"


def invalid_depth_fraction(v: View, cfg: PointCloudConfig) -> float:
    """Fraction of ``v``'s depth pixels that are holes or outside [min_depth, max_depth] (1.0 without depth)."""
    if v.depth is None or v.depth.size == 0:
        return 1.0
    d = v.depth
    ok = (d >= cfg.min_depth) & (d <= cfg.max_depth)  # NaN holes compare False
    return 1.0 - float(np.count_nonzero(ok)) / d.size


def check_usable_depth(views: Sequence[View], cloud: FusedCloud, cfg: PointCloudConfig) -> None:
    """Raise ``SceneError`` naming the views when the fused cloud of ``views`` is empty.

    Without a single voxel nothing can be segmented; finishing with "0 instances" would
    hide that the input was unusable (issue 14: all-zero depth maps "succeeded").
    """
    if cloud.num > 0:
        return
    names = ", ".join(_label(v) for v in views)
    fractions = [invalid_depth_fraction(v, cfg) for v in views]
    if all(f >= 1.0 for f in fractions):
        why = f"every depth pixel is a hole (0) or outside {cfg.min_depth:g}-{cfg.max_depth:g} m"
    else:
        why = f"too few depth points to fill one {cfg.voxel_size * 1000:g} mm voxel with {cfg.min_points} points"
    raise SceneError(f"no usable depth in any view ({why}): {names}")


def view_warnings(views: Sequence[View], cloud: FusedCloud, cfg: PointCloudConfig) -> tuple[RunWarning, ...]:
    """The view checks of the module docstring, for ``views`` fused (in this order) into ``cloud``."""
    out: list[RunWarning] = []
    vis = cloud.visible()
    fed = vis.sum(axis=1)
    # voxels fed by at least two views: a view's voxel is shared when it is among them
    shared = vis.sum(axis=0) >= 2
    multi = len(views) >= 2
    for i, v in enumerate(views):
        lab = _label(v)
        frac = invalid_depth_fraction(v, cfg)
        if fed[i] == 0:
            out.append(RunWarning(
                "view-dropped",
                f"{lab}: no usable depth ({frac:.0%} of pixels are holes or outside "
                f"{cfg.min_depth:g}-{cfg.max_depth:g} m); the view adds nothing to the 3D cloud",
                v.frame, v.name))
        else:
            if frac > DEPTH_INVALID_FRACTION:
                out.append(RunWarning(
                    "depth-invalid",
                    f"{lab}: {frac:.0%} of the depth pixels are holes or outside "
                    f"{cfg.min_depth:g}-{cfg.max_depth:g} m; the view adds little to the 3D cloud",
                    v.frame, v.name))
            if multi:
                overlap = float(np.count_nonzero(vis[i] & shared)) / float(fed[i])
                if overlap < MIN_VIEW_OVERLAP:
                    out.append(RunWarning(
                        "view-isolated",
                        f"{lab}: only {overlap:.0%} of what it sees is seen by another view (check its pose); "
                        "its masks cannot be matched across views",
                        v.frame, v.name))
        if v.masks is not None and len(v.masks) == 0:
            out.append(RunWarning("view-no-masks", f"{lab}: no mask candidates; the view adds no 2D evidence",
                                  v.frame, v.name))
    return tuple(out)
