"""The pose fit's speed-ups change no bit of its result: the hand-written Adam against torch's."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

torch = pytest.importorskip("torch")

from clutt3r_core.update.pose import _Adam  # noqa: E402


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), n=st.integers(1, 40))
def test_adam_bit_identical_to_torch(seed: int, n: int) -> None:
    rng = np.random.default_rng(seed)
    w0, t0 = rng.normal(size=3), rng.normal(size=3)
    ws = [torch.tensor(w0, requires_grad=True) for _ in range(2)]
    ts = [torch.tensor(t0, requires_grad=True) for _ in range(2)]
    ref = torch.optim.Adam([{"params": [ws[0]], "lr": 0.05}, {"params": [ts[0]], "lr": 0.01}])
    ours = _Adam(torch, [{"params": [ws[1]], "lr": 0.05}, {"params": [ts[1]], "lr": 0.01}])
    for i in range(n):
        f = 0.1 ** (i / max(n - 1, 1))  # the schedule's decay: lr changes every step
        scale = 10.0 ** rng.uniform(-6, 2)
        gw, gt = rng.normal(size=3) * scale, rng.normal(size=3) * scale
        for opt, w, t in ((ref, ws[0], ts[0]), (ours, ws[1], ts[1])):
            for g, lr in zip(opt.param_groups, (0.05, 0.01)):
                g["lr"] = lr * f
            opt.zero_grad()
            assert w.grad is None and t.grad is None
            loss = (w * torch.tensor(gw)).sum() + (t * torch.tensor(gt)).sum()
            loss.backward()
            opt.step()
        assert torch.equal(ws[0], ws[1]) and torch.equal(ts[0], ts[1])


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 40), w=st.integers(1, 40),
       density=st.floats(0.0, 0.5), grow=st.integers(0, 5))
def test_near_outside_matches_distance_transform(seed: int, h: int, w: int, density: float, grow: int) -> None:
    """The contour test of the loss: the same booleans as the former full distance transform."""
    from scipy import ndimage

    from clutt3r_core.update.pose import _near_outside

    rng = np.random.default_rng(seed)
    sil = rng.random((h, w)) < density
    if grow:
        sil = ndimage.binary_dilation(sil, iterations=grow)
    flat = rng.integers(0, h * w, 80)
    reach = rng.integers(0, 13, 80) + 1.5  # splat radii 0..12 (project._MAX_RADIUS) + 1.5
    ref = ndimage.distance_transform_edt(np.pad(sil, 1))[1:-1, 1:-1].reshape(-1)[flat] <= reach
    assert np.array_equal(_near_outside(sil, flat, reach), ref)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), h=st.integers(1, 60), w=st.integers(1, 60), r=st.integers(0, 12),
       fill=st.floats(0.0, 1.0))
def test_zbuf_filter_matches_scipy_minimum_filter(seed: int, h: int, w: int, r: int, fill: float) -> None:
    """project._zbuf_by_filter's OpenCV erosion: scipy's constant-inf minimum filter, bit for bit."""
    import cv2
    from scipy.ndimage import minimum_filter

    rng = np.random.default_rng(seed)
    a = np.where(rng.random((h, w)) < fill, rng.uniform(0.05, 5.0, (h, w)), np.inf)
    ref = minimum_filter(a, size=2 * r + 1, mode="constant", cval=np.inf)
    out = cv2.erode(a, np.ones((2 * r + 1, 2 * r + 1), np.uint8), borderType=cv2.BORDER_CONSTANT,
                    borderValue=np.inf)
    assert out.dtype == np.float64 and np.array_equal(out, ref)
