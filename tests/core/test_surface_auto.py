"""The fusion's noise-aware parts: the views' depth disagreement, ``surface="auto"``, and the move
limit of the surface estimate (``clutt3r_core.surface``, issue 13)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from clutt3r_core.errors import SceneError
from clutt3r_core.pointcloud import PointCloudConfig, fuse_views
from clutt3r_core.depth_agreement import DepthAgreement, depth_disagreement
from clutt3r_core.surface import snap_to_surface
from clutt3r_core.synth.sensor import quantise_mm
from tests.core._geometry_scenes import make_views
from tests.core.test_surface import _noisy

AUTO = PointCloudConfig(surface="auto")
PLAIN = PointCloudConfig(surface="voxel-mean")


@pytest.fixture(scope="module")
def clean_views():
    return make_views(3, 320, 240, 400.0)


def _quantised(views):
    return [dataclasses.replace(v, depth=quantise_mm(v.depth)) for v in views]


@settings(max_examples=10, deadline=None)
@given(sigma=st.floats(0.0005, 0.005), seed=st.integers(0, 2**16))
def test_disagreement_measures_white_noise(sigma, seed):
    """White depth noise of sigma per view reads 0.8-1.0 sigma (the other view is read bilinearly,
    which averages part of its noise), whatever the views' order."""
    views = _noisy(make_views(3, 320, 240, 400.0), sigma, seed)
    a = depth_disagreement(views, [1, 1, 1])
    assert 0.75 * sigma < a.sigma < 1.05 * sigma, (a.sigma, sigma)
    assert a.pairs > 5000
    b = depth_disagreement(views[::-1], [1, 1, 1])
    assert b.sigma == pytest.approx(a.sigma, rel=1e-9)


def test_disagreement_of_clean_and_quantised_depth(clean_views):
    """Exact depth: the views agree to the float; whole-millimetre depth: about the rounding's own
    0.29 mm, far below ``PointCloudConfig.surface_auto_sigma``."""
    assert depth_disagreement(clean_views, [1, 1, 1]).sigma < 1e-5
    q = depth_disagreement(_quantised(clean_views), [1, 1, 1]).sigma
    assert 0.2e-3 < q < 0.4e-3 < PointCloudConfig().surface_auto_sigma


def test_disagreement_needs_two_views(clean_views):
    one = depth_disagreement(clean_views[:1], [1])
    assert np.isnan(one.sigma) and one.pairs == 0
    with pytest.raises(SceneError):
        DepthAgreement(-1.0, 3)


def test_auto_keeps_the_plain_fusion_on_clean_depth(clean_views):
    """Below the threshold ``auto`` is the plain fusion, bit for bit, and says so."""
    views = _quantised(clean_views)
    plain = fuse_views(views, PLAIN)
    auto = fuse_views(views, AUTO)
    assert plain.surface is None
    assert auto.surface.method == "voxel-mean" and auto.surface.disagreement < AUTO.surface_auto_sigma
    np.testing.assert_array_equal(auto.points, plain.points)
    np.testing.assert_array_equal(auto.counts, plain.counts)


def test_auto_runs_the_surface_estimate_on_noisy_depth(clean_views):
    """At 3 mm of noise ``auto`` is ``tsdf``, bit for bit, and records the measured disagreement."""
    views = _noisy(clean_views, 0.003, seed=5)
    tsdf = fuse_views(views, PointCloudConfig(surface="tsdf"))
    auto = fuse_views(views, AUTO)
    assert auto.surface.method == "tsdf" == tsdf.surface.method
    assert auto.surface.disagreement > AUTO.surface_auto_sigma
    assert np.isnan(tsdf.surface.disagreement)  # not measured when tsdf is asked for
    np.testing.assert_array_equal(auto.points, tsdf.points)
    # the threshold decides: raised above the measured disagreement, auto is the plain fusion
    high = fuse_views(views, dataclasses.replace(AUTO, surface_auto_sigma=0.01))
    assert high.surface.method == "voxel-mean"
    np.testing.assert_array_equal(high.points, fuse_views(views, PLAIN).points)


def test_auto_is_the_default():
    assert PointCloudConfig().surface == "auto"


def test_config_rejects_a_negative_threshold():
    with pytest.raises(SceneError):
        PointCloudConfig(surface_auto_sigma=-0.001)


def test_move_limit_follows_the_measured_noise(clean_views):
    """Clean, whole-millimetre depth: the moves' measured noise is the rounding's (under 1 mm at
    1 m) and no point moves more than noise_k times it at its depth; with 3 mm white noise the
    measured noise is several times larger and the noise's own moves are kept."""
    from clutt3r_core.surface import SurfaceParams

    def run(views):
        P, z = [], []
        for v in views:
            p, _ = v.camera.backproject(v.depth)
            P.append(p.astype(np.float32))
            T = v.camera.T_camera_world
            z.append(p @ T[2, :3] + T[2, 3])
        P, z = np.concatenate(P), np.concatenate(z)
        return P, z, snap_to_surface(views, P, [1, 1, 1], point_depth=z)

    P, z, sn = run(_quantised(clean_views))
    assert 0 < sn.move_noise < 1e-3
    shift = np.linalg.norm(sn.points - P, axis=1)
    assert np.all(shift[sn.moved] <= SurfaceParams().noise_k * sn.move_noise * z[sn.moved] ** 2 * (1 + 1e-4) + 1e-6)
    assert sn.moved.mean() > 0.8
    Pn, zn, snn = run(_noisy(clean_views, 0.003, seed=7))
    assert snn.move_noise > 5 * sn.move_noise
    assert snn.moved.mean() > 0.8


@pytest.mark.parametrize("sigma", [0.0, 0.003])
def test_the_trace_records_the_fusion_choice(clean_views, sigma, tmp_path):
    """``segment`` keeps what the fusion measured and did in its trace, and a saved trace reads it
    back (NaN, not measured, is stored as JSON null)."""
    from clutt3r_core.pipeline import segment
    from clutt3r_core.scene import Scene
    from clutt3r_core.segmentation.trace import load_trace, save_trace

    views = _noisy(clean_views, sigma, seed=3) if sigma else _quantised(clean_views)
    seg = segment(Scene(views=tuple(views), initial=tuple(range(len(views)))))
    s = seg.trace.surface
    assert s.method == ("tsdf" if sigma else "voxel-mean")
    assert (s.disagreement > AUTO.surface_auto_sigma) == bool(sigma)
    assert np.isnan(s.move_noise) != bool(sigma)
    back = load_trace(save_trace(seg.trace, tmp_path)).surface
    assert back.method == s.method and back.disagreement == s.disagreement
    assert back.move_noise == s.move_noise or (np.isnan(back.move_noise) and np.isnan(s.move_noise))
