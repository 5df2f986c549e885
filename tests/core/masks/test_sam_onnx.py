"""The sam-onnx backend's wiring, with a tiny ONNX encoder/decoder pair built by the test.

This checks WIRING, not quality: the tiny "decoder" is not SAM; it answers every point prompt
with a disc of logits around the point (4 outputs of different radii, like SAM's
single-mask + 3 multimask outputs) at SAM's low-res 256x256 padded-input frame. The test
checks that preprocessing, the prompt encoding (scaled coordinates + the padding point),
the output post-processing back to the view, stability filtering and NMS produce masks
where the prompts were.
"""

from __future__ import annotations

import numpy as np
import pytest

from clutt3r_core.errors import Clutt3rError, SceneFileError
from clutt3r_core.masks import create_mask_generator
from clutt3r_core.masks.sam_onnx import SamOnnxConfig
from tests.core.masks._box_scene import box_view

torch = pytest.importorskip("torch")
pytest.importorskip("onnx", reason="onnx not installed (test extra): the tiny model cannot be exported")


class _Encoder(torch.nn.Module):
    def forward(self, image):  # (1, 3, 1024, 1024) -> (1, 8, 64, 64)
        x = torch.nn.functional.avg_pool2d(image, 16)
        return torch.cat([x, x, x[:, :2]], dim=1)


class _Decoder(torch.nn.Module):
    def forward(self, image_embeddings, point_coords, point_labels, mask_input, has_mask_input, orig_im_size):
        # pixel centres of the 256x256 low-res frame, in 1024-input coordinates
        g = (torch.arange(256, dtype=torch.float32) + 0.5) * 4.0
        p = point_coords[0, 0]  # the first (real) prompt point
        d = torch.sqrt((g[None, :] - p[0]) ** 2 + (g[:, None] - p[1]) ** 2)
        radii = torch.tensor([60.0, 30.0, 60.0, 120.0]).reshape(4, 1, 1)
        logits = (radii - d[None]) * 4.0  # steep edges: stable masks (stability ~0.97 at radius 30)
        used = image_embeddings.mean() * 0 + mask_input.mean() * 0 + has_mask_input.sum() * 0 + orig_im_size.sum() * 0
        used = used + point_labels.sum() * 0
        iou = torch.tensor([[0.9, 0.95, 0.93, 0.89]]) + used
        return logits[None] + used, iou


def _export(tmp_path):
    enc, dec = tmp_path / "enc.onnx", tmp_path / "dec.onnx"
    torch.onnx.export(_Encoder(), (torch.zeros(1, 3, 1024, 1024),), str(enc), input_names=["image"],
                      output_names=["image_embeddings"], dynamo=False)
    args = (torch.zeros(1, 8, 64, 64), torch.zeros(1, 2, 2), torch.zeros(1, 2), torch.zeros(1, 1, 256, 256),
            torch.zeros(1), torch.tensor([480.0, 640.0]))
    torch.onnx.export(_Decoder(), args, str(dec),
                      input_names=["image_embeddings", "point_coords", "point_labels", "mask_input", "has_mask_input",
                                   "orig_im_size"],
                      output_names=["masks", "iou_predictions"], dynamo=False)
    return enc, dec


@pytest.mark.filterwarnings("ignore")
def test_tiny_onnx_pair_wiring(tmp_path):
    enc, dec = _export(tmp_path)
    cfg = SamOnnxConfig(points_per_side=2, nms_iou=0.7)
    gen = create_mask_generator("sam-onnx", encoder=enc, decoder=dec, config=cfg)
    assert gen.name == "sam-onnx"
    view, _ = box_view(width=320, height=240)
    c = gen.generate(view)
    H, W = 240, 320
    assert c.shape == (H, W) and len(c) > 0
    # 2x2 grid: prompts at (80, 60), (240, 60), (80, 180), (240, 180) view pixels; the scale to
    # the 1024 input is 3.2, so output 1 (radius 30 input px) is a disc of ~9.4 view px there
    scale = 1024 / 320
    vs, us = np.mgrid[0:H, 0:W]
    expected = []
    for u in (80.0, 240.0):
        for v in (60.0, 180.0):
            expected.append(np.hypot(us + 0.5 - u - 0.5, vs + 0.5 - v - 0.5) * scale < 30)
    ious = np.array([[(m & e).sum() / (m | e).sum() for m in c.masks] for e in expected])
    assert (ious.max(axis=1) > 0.8).all(), ious.max(axis=1)
    # output 3 (iou 0.89 >= 0.88) is kept too; output 0 (single-mask output) is not used with 4 outputs
    big = [np.hypot(us - u, vs - v) * scale < 120 for u in (80.0, 240.0) for v in (60.0, 180.0)]
    assert max((m & b).sum() / (m | b).sum() for m in c.masks for b in big) > 0.8
    assert c.scores is not None and (c.scores <= 1).all()


def test_no_download_path_and_clear_errors(tmp_path):
    with pytest.raises(Clutt3rError, match="needs --sam-encoder PATH and --sam-decoder PATH"):
        create_mask_generator("sam-onnx")
    with pytest.raises(SceneFileError, match="ONNX model not found"):
        create_mask_generator("sam-onnx", encoder=tmp_path / "e.onnx", decoder=tmp_path / "d.onnx")
    (tmp_path / "e.onnx").write_bytes(b"garbage")
    (tmp_path / "d.onnx").write_bytes(b"garbage")
    with pytest.raises(SceneFileError, match="not a loadable ONNX model"):
        create_mask_generator("sam-onnx", encoder=tmp_path / "e.onnx", decoder=tmp_path / "d.onnx")
