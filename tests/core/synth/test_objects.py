"""Object registry: curated YCB models load, are centred, coloured and banded."""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.errors import SceneError
from clutt3r_core.synth.objects import REGISTRY, load_object, registry_keys, spec_of


def test_registry_is_curated_and_named():
    keys = registry_keys()
    assert len(keys) >= 30 and len(set(keys)) == len(keys)
    cats = {s.category for s in REGISTRY}
    assert {"banana", "mug", "cracker box", "bowl", "soup can"} <= cats


@pytest.mark.parametrize("key", ["003_cracker_box", "025_mug", "011_banana"])
def test_load_centres_and_colours(key):
    o = load_object(key)
    assert load_object(key) is o  # cached
    assert np.allclose((o.vertices.max(0) + o.vertices.min(0)) / 2, 0, atol=1e-9)
    assert o.faces.dtype == np.int32 and o.face_colors.shape == (len(o.faces), 3)
    assert 0.01 < o.extent.max() < 0.35  # metres
    assert 0.02 <= o.mass <= 1.5 and 4 <= len(o.hull_points) <= 96
    if spec_of(key).band is not None:  # the label band gives a second colour
        body = np.asarray(spec_of(key).color, float)
        far = np.linalg.norm(o.face_colors.astype(float) - body, axis=1) > 60
        assert 0.05 < far.mean() < 0.8


def test_unknown_model():
    with pytest.raises(SceneError, match="unknown synthetic object"):
        spec_of("000_nothing")
