"""Depth-sensor noise: z^2 growth, holes at depth edges, millimetre grid."""

from __future__ import annotations

import numpy as np

from clutt3r_core.synth.sensor import DEPTH_NOISE_PRESETS, apply_depth_noise, quantise_mm


def test_none_only_quantises():
    d = np.full((60, 80), 0.61234, np.float32)
    d[0, 0] = np.nan
    out = apply_depth_noise(d, np.ones_like(d), 100.0, DEPTH_NOISE_PRESETS["none"], np.random.default_rng(0))
    assert np.isnan(out[0, 0]) and np.allclose(out[1:], 0.612)
    assert np.array_equal(out, quantise_mm(d), equal_nan=True)


def test_noise_grows_with_square_of_depth():
    cfg = DEPTH_NOISE_PRESETS["realsense"]
    stds = []
    for z in (0.5, 1.0):
        d = np.full((240, 320), z, np.float32)
        out = apply_depth_noise(d, np.ones_like(d), 200.0, cfg, np.random.default_rng(1))
        stds.append(np.nanstd(out))
    assert 2.5 < stds[1] / stds[0] < 6.0  # ~4 for z^2


def test_depth_noise_does_not_depend_on_the_image_size():
    # the same camera at 640 and 160 px (fx scaled with the width): the same depth error in metres
    cfg = DEPTH_NOISE_PRESETS["realsense"]
    stds = []
    for w, fx in ((640, 400.0), (160, 100.0)):
        d = np.full((w * 3 // 4, w), 0.6, np.float32)
        stds.append(np.nanstd(apply_depth_noise(d, np.ones_like(d), fx, cfg, np.random.default_rng(3))))
    assert 0.7 < stds[1] / stds[0] < 1.4


def test_holes_at_depth_edges_and_grazing_angles():
    cfg = DEPTH_NOISE_PRESETS["realsense"]
    d = np.full((100, 100), 0.8, np.float32)
    d[:, 50:] = 0.5
    cos = np.ones_like(d)
    cos[:10] = 0.05  # grazing strip
    out = apply_depth_noise(d, cos, 100.0, cfg, np.random.default_rng(2))
    edge_holes = np.isnan(out[20:, 48:52]).mean()
    far_holes = np.isnan(out[20:, 10:40]).mean()
    assert edge_holes > 0.3 and far_holes < 0.01
    assert np.isnan(out[:10]).mean() > 0.3
    v = out[np.isfinite(out)]
    assert np.allclose(v * 1000, np.round(v * 1000), atol=1e-3)
