"""Viewer fixtures: one tiny generated scene, segmented once per session with a fake text embedder.

The fake embedder embeds masks exactly as 'appearance-hsv' does and embeds a colour word
("red", "green", ...) as the descriptor of a solid patch of that colour, so a query
ranks instances by colour: enough to drive the Query tab's callback path end to end.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from clutt3r_viewer.headless import free_port  # noqa: F401 (the browser tests import it from here)
from clutt3r_core.embeddings import AppearanceEmbedder, register_embedder

COLOURS = {"red": (220, 30, 30), "green": (30, 200, 40), "blue": (30, 60, 220), "yellow": (230, 220, 30),
           "white": (240, 240, 240), "black": (15, 15, 15), "orange": (240, 140, 20)}


@dataclass(frozen=True)
class FakeTextEmbedder:
    name: str = "fake-text"

    @property
    def dim(self) -> int:
        return AppearanceEmbedder().dim

    def embed_masks(self, rgb, masks):
        return AppearanceEmbedder().embed_masks(rgb, masks)

    def embed_text(self, texts):
        out = []
        for t in texts:
            col = COLOURS.get(t.strip().lower().split()[0] if t.strip() else "", (128, 128, 128))
            patch = np.zeros((8, 8, 3), np.uint8) + np.array(col, np.uint8)
            out.append(AppearanceEmbedder().embed_masks(patch, np.ones((1, 8, 8), bool))[0])
        return np.stack(out).astype(np.float32)


register_embedder("fake-text", FakeTextEmbedder)


@pytest.fixture(scope="session")
def tiny_scene():
    from clutt3r_core.synth import SynthConfig, generate_scene

    return generate_scene(SynthConfig(seed=3, preset="easy", views=4, width=320, height=240, focal_px=200.0),
                          progress=False)


@pytest.fixture(scope="session")
def tiny_seg(tiny_scene):
    from clutt3r_core.pipeline import SegmentConfig, segment

    seg = segment(tiny_scene, SegmentConfig(embedder="fake-text"))
    assert 0 < len(seg.points) < 100_000
    assert seg.num_instances > 0 and len(seg.trace.grouping.events) > 0
    return seg


@pytest.fixture(scope="session")
def tiny_data(tiny_seg, tiny_scene):
    from clutt3r_viewer.data import build_viewer_data

    return build_viewer_data(tiny_seg, tiny_scene)


@pytest.fixture(scope="session")
def tiny_run_dir(tiny_seg, tiny_scene, tmp_path_factory) -> Path:
    from clutt3r_core.io import write_sample_layout
    from clutt3r_core.pipeline import save_run
    from clutt3r_viewer.loading import write_viewer_link

    root = tmp_path_factory.mktemp("viewer_run")
    scene_dir = root / "scene"
    write_sample_layout(tiny_scene, scene_dir)
    save_run(tiny_seg, root / "run")
    write_viewer_link(root / "run", scene_dir)
    return root / "run"


@pytest.fixture
def artifacts() -> Path:
    p = Path(__file__).resolve().parents[2] / "test-artifacts"
    p.mkdir(exist_ok=True)
    return p
