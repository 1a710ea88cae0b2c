"""Run a trained detector on full frames: the network input, NMS, and boxes back in frame pixels.

A frame reaches the network at its native resolution, padded on the right and bottom to a multiple of 32
(`image_size=None`; 640x480 needs no padding), or letterboxed to a square of `image_size` pixels.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import torch

from spacetrack.data.yolo_dataset import letterbox, pad_to_stride
from spacetrack.engine.nms import non_max_suppression


def check_image_size(image_size: int | None) -> None:
    """A letterbox size must be a multiple of the network's largest stride (None: native frames)."""
    if image_size is not None and image_size % 32:
        raise ValueError(f"image_size must be a multiple of 32 pixels (or null: native), got {image_size}")


def network_input(frame: np.ndarray, image_size: int | None) -> tuple[np.ndarray, float, tuple[int, int]]:
    """(image the network sees, scale, (pad_x, pad_y)) of an RGB uint8 frame: frame pixels map to input
    pixels as `x * scale + pad_x`."""
    check_image_size(image_size)
    if image_size is None:
        return pad_to_stride(frame), 1.0, (0, 0)
    return letterbox(frame, image_size)


def to_frame_boxes(det: np.ndarray, scale: float, pad: tuple[int, int], shape: Sequence[int]) -> np.ndarray:
    """(n, 6) `x1, y1, x2, y2, score, class` rows in network-input pixels -> frame pixels, clipped to the
    (H, W) frame; boxes left with no area are dropped."""
    det = np.asarray(det, dtype=np.float64).copy()
    det[:, [0, 2]] = ((det[:, [0, 2]] - pad[0]) / scale).clip(0, shape[1])
    det[:, [1, 3]] = ((det[:, [1, 3]] - pad[1]) / scale).clip(0, shape[0])
    return det[(det[:, 2] > det[:, 0]) & (det[:, 3] > det[:, 1])]


def frame_detections(
    predictions: torch.Tensor,
    prepared: Sequence[tuple[np.ndarray, float, tuple[int, int]]],
    shapes: Sequence[Sequence[int]],
    *,
    conf_threshold: float,
    iou_threshold: float,
    max_det: int,
    score: str = "class",
    agnostic: bool = False,
) -> list[np.ndarray]:
    """NMS of decoded network predictions (B, N, 5 + classes), then per frame an (n, 6) float array
    `x1, y1, x2, y2, score, class` in the pixels of that frame (its `network_input` in `prepared`, its
    (H, W) in `shapes`), best score first; `score` and `agnostic` as in `non_max_suppression`."""
    detections = non_max_suppression(
        predictions,
        conf_threshold=conf_threshold,
        iou_threshold=iou_threshold,
        max_det=max_det,
        score=score,
        agnostic=agnostic,
    )
    return [
        to_frame_boxes(det.cpu().numpy(), scale, pad, shape)
        for shape, (_, scale, pad), det in zip(shapes, prepared, detections, strict=True)
    ]


@torch.no_grad()
def detect(
    model: torch.nn.Module,
    frames: Sequence[np.ndarray],
    *,
    image_size: int | None = None,
    conf_threshold: float = 0.25,
    iou_threshold: float = 0.45,
    max_det: int = 300,
) -> list[np.ndarray]:
    """Per RGB uint8 (H, W, 3) frame an (n, 6) float array `x1, y1, x2, y2, score, class` (xyxy pixels
    of that frame, clipped to it; boxes with no area left out), best score first. `model` is a `YOLOv5`
    in eval mode (or anything with its `predict`); frames of one call share a size.
    """
    prepared = [network_input(frame, image_size) for frame in frames]
    device = next(iter(model.parameters()), torch.zeros(())).device
    x = torch.from_numpy(np.stack([p[0] for p in prepared])).to(device).permute(0, 3, 1, 2).float() / 255
    return frame_detections(
        model.predict(x).float(),
        prepared,
        [frame.shape for frame in frames],
        conf_threshold=conf_threshold,
        iou_threshold=iou_threshold,
        max_det=max_det,
    )
