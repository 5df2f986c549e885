"""The ``sam-onnx`` mask generator: SAM-family models exported to ONNX, run with onnxruntime.

For users who have weights: a SAM / MobileSAM image encoder and prompt decoder exported to
ONNX (segment-anything's ``scripts/export_onnx_model.py`` for the decoder; the encoder
exported the same way by e.g. ``samexporter``), loaded from local paths. Nothing is ever
downloaded. The automatic mask generation follows SAM's ``SamAutomaticMaskGenerator``
(Kirillov et al. 2023, Sec. 4 / App. A): a regular point grid, one single-point prompt per
grid point, every multimask output kept if its predicted IoU and its *stability score*
(IoU of the mask thresholded at logit +offset and -offset) are high enough, then
non-maximum suppression by mask IoU, then a minimum area.

Interface expected (the segment-anything export's names; inputs the decoder does not
declare are simply not fed):

* encoder: one input, (1, 3, S, S) float32, the image resized so its longest side is S
  (1024 for SAM), normalised with ImageNet mean/std on 0-255 values, zero-padded
  bottom/right; one output, the image embedding.
* decoder: ``image_embeddings``, ``point_coords`` (1, N, 2) in the resized frame,
  ``point_labels`` (1, N) (a padding point (0, 0) with label -1 is appended, as SAM's ONNX
  export expects), ``mask_input`` (1, 1, S/4, S/4), ``has_mask_input`` (1,),
  ``orig_im_size`` (2,); outputs mask logits (1, K, h, w) and IoU predictions (1, K).
  Masks at the view's size are used as they are; any other size is taken to be the padded
  S x S input frame (SAM's ``low_res_masks``) and is cropped and resized back. With K = 4
  (``return_single_mask=False``) outputs 1..3 (the multimask outputs) are used, as SAM does
  for single-point prompts.

EfficientSAM's export has different input names and is not supported by this wiring yet.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from clutt3r_core.errors import Clutt3rError, SceneFileError
from clutt3r_core.scene import MaskCandidates, View

__all__ = ["SamOnnxConfig", "SamOnnxMaskGenerator"]

_MEAN = np.array([123.675, 116.28, 103.53], np.float32)
_STD = np.array([58.395, 57.12, 57.375], np.float32)


@dataclass(frozen=True)
class SamOnnxConfig:
    """Automatic mask generation settings (defaults: segment-anything's
    ``SamAutomaticMaskGenerator`` defaults, except the grid, 16 instead of 32 per side, for CPU time).

    Attributes:
        points_per_side: the prompt grid is points_per_side^2 points over the image.
        pred_iou_thresh: keep a mask whose predicted IoU is at least this.
        stability_thresh: keep a mask whose stability score is at least this.
        stability_offset: logit offset of the stability score.
        nms_iou: of two masks with mask IoU above this, the lower-scored one is dropped.
        min_area_frac: smallest mask, fraction of the image.
        input_size: the encoder's square input side, pixels (1024 for SAM / MobileSAM).
    """

    points_per_side: int = 16
    pred_iou_thresh: float = 0.88
    stability_thresh: float = 0.95
    stability_offset: float = 1.0
    nms_iou: float = 0.7
    min_area_frac: float = 4e-4
    input_size: int = 1024


class SamOnnxMaskGenerator:
    """``MaskGenerator`` ``sam-onnx``: see the module docstring.

    Args:
        encoder: path of the image-encoder ``.onnx``.
        decoder: path of the prompt-decoder ``.onnx``.
        config: automatic mask generation settings.
    """

    name = "sam-onnx"

    def __init__(self, encoder: str | Path | None = None, decoder: str | Path | None = None,
                 config: SamOnnxConfig | None = None, threads: int = 0) -> None:
        import onnxruntime as ort

        if encoder is None or decoder is None:
            raise Clutt3rError("the sam-onnx mask generator needs --sam-encoder PATH and --sam-decoder PATH"
                               " (local .onnx files; nothing is downloaded)")
        self.config = config or SamOnnxConfig()
        opts = ort.SessionOptions()
        if threads:
            opts.intra_op_num_threads = threads
        sessions = []
        for p in (Path(encoder), Path(decoder)):
            if not p.is_file():
                raise SceneFileError(p, "ONNX model not found")
            try:
                sessions.append(ort.InferenceSession(str(p), opts, providers=["CPUExecutionProvider"]))
            except Exception as e:  # onnxruntime raises its own exception types
                raise SceneFileError(p, f"not a loadable ONNX model ({type(e).__name__}: {e})") from None
        self.encoder, self.decoder = sessions
        self._dec_inputs = {i.name for i in self.decoder.get_inputs()}
        need = {"image_embeddings", "point_coords", "point_labels"}
        if not need <= self._dec_inputs:
            raise SceneFileError(Path(decoder), f"decoder inputs {sorted(self._dec_inputs)} lack {sorted(need - self._dec_inputs)}"
                                 " (expected segment-anything's ONNX export)")
        if len(self.encoder.get_inputs()) != 1:
            raise SceneFileError(Path(encoder), "encoder must have exactly one input (the image)")

    def _embed(self, rgb: np.ndarray) -> tuple[np.ndarray, float]:
        S = self.config.input_size
        H, W = rgb.shape[:2]
        scale = S / max(H, W)
        nh, nw = int(round(H * scale)), int(round(W * scale))
        img = cv2.resize(rgb, (nw, nh), interpolation=cv2.INTER_LINEAR).astype(np.float32)
        img = (img - _MEAN) / _STD
        x = np.zeros((S, S, 3), np.float32)
        x[:nh, :nw] = img
        x = x.transpose(2, 0, 1)[None]
        emb = self.encoder.run(None, {self.encoder.get_inputs()[0].name: x})[0]
        return emb, scale

    def _to_view(self, logits: np.ndarray, H: int, W: int, scale: float) -> np.ndarray:
        if logits.shape == (H, W):
            return logits
        S = self.config.input_size
        full = cv2.resize(logits, (S, S), interpolation=cv2.INTER_LINEAR)
        nh, nw = int(round(H * scale)), int(round(W * scale))
        return cv2.resize(full[:nh, :nw], (W, H), interpolation=cv2.INTER_LINEAR)

    def generate(self, view: View) -> MaskCandidates:
        cfg = self.config
        H, W = view.camera.height, view.camera.width
        emb, scale = self._embed(view.rgb)
        n = cfg.points_per_side
        offs = (np.arange(n) + 0.5) / n
        grid = np.stack(np.meshgrid(offs * W, offs * H), axis=-1).reshape(-1, 2)
        masks, scores = [], []
        S = cfg.input_size
        for u, v in grid:
            feed = {
                "image_embeddings": emb,
                "point_coords": np.array([[[u * scale, v * scale], [0.0, 0.0]]], np.float32),
                "point_labels": np.array([[1.0, -1.0]], np.float32),
                "mask_input": np.zeros((1, 1, S // 4, S // 4), np.float32),
                "has_mask_input": np.zeros((1,), np.float32),
                "orig_im_size": np.array([H, W], np.float32),
            }
            out = self.decoder.run(None, {k: v_ for k, v_ in feed.items() if k in self._dec_inputs})
            lg = np.asarray(out[0], np.float32)[0]
            iou = np.asarray(out[1], np.float32).reshape(-1)
            sel = range(1, 4) if lg.shape[0] == 4 else range(lg.shape[0])
            for k in sel:
                if iou[k] < cfg.pred_iou_thresh:
                    continue
                l = self._to_view(lg[k], H, W, scale)
                hi = (l > cfg.stability_offset).sum()
                lo = (l > -cfg.stability_offset).sum()
                stab = hi / lo if lo else 0.0
                if stab < cfg.stability_thresh:
                    continue
                m = l > 0
                if m.sum() < cfg.min_area_frac * H * W:
                    continue
                masks.append(m)
                scores.append(float(iou[k]) * float(stab))
        if not masks:
            return MaskCandidates.empty(H, W)
        keep = _mask_nms(np.stack(masks), np.asarray(scores), cfg.nms_iou)
        stack = np.stack([masks[i] for i in keep])
        return MaskCandidates(stack, np.arange(1, len(keep) + 1, dtype=np.int32),
                              np.clip(np.asarray([scores[i] for i in keep], np.float32), 0, 1))


def _mask_nms(masks: np.ndarray, scores: np.ndarray, thresh: float) -> list[int]:
    """Greedy NMS by mask IoU (on an 4x-subsampled grid: IoU changes by well under 1 %)."""
    from clutt3r_core.masks.quality import mask_iou_matrix

    small = masks[:, ::4, ::4]
    iou = mask_iou_matrix(small, small)
    order = np.argsort(-scores, kind="stable")
    keep: list[int] = []
    for i in order:
        if all(iou[i, j] <= thresh for j in keep):
            keep.append(int(i))
    return keep
