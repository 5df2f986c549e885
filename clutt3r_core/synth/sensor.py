"""RealSense-like depth-sensor noise for synthetic views (optional).

An active-stereo camera such as the Intel RealSense D435 (the paper's robot camera,
Sec. IV) measures disparity ``d = f * b / z``; a roughly constant sub-pixel disparity
error therefore grows like ``z^2 / (f b)`` in depth. Matching fails at depth edges
(occlusion shadows next to foreground objects) and on surfaces seen at grazing angles,
leaving holes. Depth is finally stored in whole millimetres (uint16 PNG), so values are
quantised to 1 mm here too.

``apply_depth_noise(depth, cos_incidence, fx, cfg, rng)`` returns the noisy depth
(float32 metres, NaN = hole, on the millimetre grid).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np

from clutt3r_core.errors import SceneError

__all__ = ["DepthNoiseConfig", "DEPTH_NOISE_PRESETS", "DepthNoiseName", "depth_noise_preset", "apply_depth_noise",
           "quantise_mm"]

DepthNoiseName = Literal["none", "realsense"]


@dataclass(frozen=True)
class DepthNoiseConfig:
    """Depth noise parameters (ours, typical of a D435 at 640x480 indoors).

    Attributes:
        enabled: False = clean depth (still quantised to 1 mm).
        baseline: stereo baseline, metres (D435: 50 mm, Intel datasheet).
        disparity_sigma: per-pixel disparity noise, pixels (sub-pixel matching error,
            about 0.08 px RMS per Intel's depth-quality notes, scaled to fx at 640 px).
        correlated_sigma: disparity noise smoothed over ``correlated_px`` pixels (the blotchy,
            spatially correlated part of stereo error), pixels.
        correlated_px: correlation length of that part, pixels at 640 px width.
        edge_jump: relative depth step between neighbours that counts as a depth edge.
        edge_dropout_px: holes next to depth edges extend this far, pixels at 640 px width.
        p_edge_dropout: probability that a pixel near a depth edge is a hole.
        grazing_cos: surfaces whose |cos| of incidence is below this are at a grazing angle.
        p_grazing_dropout: probability that a grazing pixel is a hole.
        max_range: depth beyond this is a hole, metres.
    """

    enabled: bool = True
    baseline: float = 0.05
    disparity_sigma: float = 0.08
    correlated_sigma: float = 0.10
    correlated_px: float = 8.0
    edge_jump: float = 0.03
    edge_dropout_px: float = 2.0
    p_edge_dropout: float = 0.6
    grazing_cos: float = 0.18
    p_grazing_dropout: float = 0.5
    max_range: float = 4.0

    def __post_init__(self) -> None:
        for name in ("p_edge_dropout", "p_grazing_dropout"):
            v = getattr(self, name)
            if not 0 <= v <= 1:
                raise SceneError(f"DepthNoiseConfig.{name} must be in [0, 1], got {v}")
        if self.baseline <= 0 or self.max_range <= 0:
            raise SceneError("DepthNoiseConfig: baseline and max_range must be positive")


DEPTH_NOISE_PRESETS: dict[str, DepthNoiseConfig] = {
    "none": DepthNoiseConfig(enabled=False),
    "realsense": DepthNoiseConfig(),
}


def depth_noise_preset(name: str) -> DepthNoiseConfig:
    try:
        return DEPTH_NOISE_PRESETS[name]
    except KeyError:
        raise SceneError(f"unknown depth-noise preset '{name}'; choose one of {sorted(DEPTH_NOISE_PRESETS)}") from None


def quantise_mm(depth: np.ndarray) -> np.ndarray:
    """Round metres to the whole millimetre (as the uint16 mm files store them); NaN stays NaN.

    Computed exactly as the loader converts millimetres (float32 mm times float32 0.001), so
    a written and re-read depth map is bit-identical.
    """
    mm = np.round(np.asarray(depth, np.float64) * 1000.0).astype(np.float32)
    return mm * np.float32(0.001)


def apply_depth_noise(
    depth: np.ndarray,
    cos_incidence: np.ndarray,
    fx: float,
    cfg: DepthNoiseConfig,
    rng: np.random.Generator,
) -> np.ndarray:
    """Noisy, holed, millimetre-quantised copy of a clean (H, W) float32 z-depth (metres, NaN = no hit)."""
    d = np.asarray(depth, np.float32)
    if not cfg.enabled:
        return quantise_mm(d)
    import cv2

    H, W = d.shape
    scale = W / 640.0
    fb = fx * cfg.baseline
    z = d.astype(np.float64)
    hit = np.isfinite(z)
    zf = np.where(hit, z, 0.0)
    # the sigmas are pixels at 640 px width (docstring): a smaller image of the same camera has
    # coarser pixels and fx, so its disparity error in its own pixels shrinks by the same factor and
    # the depth error stays the camera's (unscaled, a 160 px image had 4x the depth noise)
    noise = rng.normal(0.0, cfg.disparity_sigma * scale, size=(H, W))
    if cfg.correlated_sigma > 0:
        k = max(1.0, cfg.correlated_px * scale)
        c = cv2.GaussianBlur(rng.normal(size=(H, W)).astype(np.float32), (0, 0), k)
        c *= cfg.correlated_sigma * scale / max(float(c.std()), 1e-9)
        noise += c
    # z' = f b / (f b / z + e)  ~  z - z^2 e / (f b)
    with np.errstate(divide="ignore", invalid="ignore"):
        zn = fb / (fb / zf + noise)
    holes = ~hit | (zn <= 0) | (zn > cfg.max_range)

    # depth edges: a relative jump to any 4-neighbour
    zpad = np.pad(np.where(hit, z, np.inf), 1, mode="edge")
    jump = np.zeros((H, W), bool)
    for dy, dx in ((0, 1), (1, 0), (2, 1), (1, 2)):
        nb = zpad[dy : dy + H, dx : dx + W]
        with np.errstate(invalid="ignore"):
            jump |= np.abs(nb - z) > cfg.edge_jump * np.minimum(nb, z)
    jump &= hit
    r = max(1, int(round(cfg.edge_dropout_px * scale)))
    near_edge = cv2.dilate(jump.astype(np.uint8), np.ones((2 * r + 1, 2 * r + 1), np.uint8)) > 0
    holes |= near_edge & (rng.uniform(size=(H, W)) < cfg.p_edge_dropout)
    grazing = hit & (np.asarray(cos_incidence) < cfg.grazing_cos)
    holes |= grazing & (rng.uniform(size=(H, W)) < cfg.p_grazing_dropout)
    zn = np.where(holes, np.nan, zn)
    return quantise_mm(zn)
