"""Run a trained detector on full frames: letterbox, predict, NMS, and boxes back in frame pixels."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from spacetrack.data.yolo_dataset import letterbox
from spacetrack.engine.nms import non_max_suppression


@torch.no_grad()
def detect(
    model: torch.nn.Module,
    frames: Sequence[np.ndarray],
    *,
    image_size: int,
    conf_threshold: float = 0.25,
    iou_threshold: float = 0.45,
    max_det: int = 300,
) -> list[np.ndarray]:
    """Per RGB uint8 (H, W, 3) frame an (n, 6) float array `x1, y1, x2, y2, score, class` (xyxy pixels
    of that frame, clipped to it), best score first. `model` is a `YOLOv5` in eval mode (or anything
    with its `predict`); `image_size` is the letterbox side it was trained at.
    """
    boxed = [letterbox(frame, image_size) for frame in frames]
    device = next(iter(model.parameters()), torch.zeros(())).device
    x = torch.from_numpy(np.stack([b[0] for b in boxed])).to(device).permute(0, 3, 1, 2).float() / 255
    detections = non_max_suppression(
        model.predict(x).float(), conf_threshold=conf_threshold, iou_threshold=iou_threshold, max_det=max_det
    )
    out = []
    for frame, (_, scale, (pad_x, pad_y)), det in zip(frames, boxed, detections, strict=True):
        det = det.cpu().numpy().astype(np.float64)
        det[:, [0, 2]] = ((det[:, [0, 2]] - pad_x) / scale).clip(0, frame.shape[1])
        det[:, [1, 3]] = ((det[:, [1, 3]] - pad_y) / scale).clip(0, frame.shape[0])
        out.append(det)
    return out
