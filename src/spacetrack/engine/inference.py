"""Run a trained detector on full frames: the network input, NMS, and boxes back in frame pixels.

A frame reaches the network at its native resolution, padded on the right and bottom to a multiple of 32
(`image_size=None`; 640x480 needs no padding), or letterboxed to a square of `image_size` pixels.
With test-time augmentation (`augmented_predictions`) the network also sees the input smaller and
mirrored, and every view's boxes go to one NMS.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F

from spacetrack.data.yolo_dataset import letterbox, pad_to_stride
from spacetrack.engine.nms import non_max_suppression

STRIDE = 32  # the network's largest stride: an input side must be a multiple of it


def check_image_size(image_size: int | None) -> None:
    """A letterbox size must be a multiple of the network's largest stride (None: native frames)."""
    if image_size is not None and image_size % STRIDE:
        raise ValueError(
            f"image_size must be a multiple of {STRIDE} pixels (or null: native), got {image_size}"
        )


def network_input(frame: np.ndarray, image_size: int | None) -> tuple[np.ndarray, float, tuple[int, int]]:
    """(image the network sees, scale, (pad_x, pad_y)) of an RGB uint8 frame: frame pixels map to input
    pixels as `x * scale + pad_x`."""
    check_image_size(image_size)
    if image_size is None:
        return pad_to_stride(frame), 1.0, (0, 0)
    return letterbox(frame, image_size)


# Test-time augmentation, YOLOv5's views: (scale, mirrored left-right) -- the input as it is, at 0.83 of
# its size mirrored, at 0.67 of its size. Each scaled size is rounded to a multiple of the largest stride.
TTA_VIEWS: tuple[tuple[float, bool], ...] = ((1.0, False), (0.83, True), (0.67, False))


def tta_views(tta) -> tuple[tuple, ...]:
    """The views of a `tta` setting: False -> none (one plain pass), True -> `TTA_VIEWS`, a sequence of
    `[scale, mirrored]` or `[scale, mirrored, max_side]` lists -> those views (a positive scale, a boolean
    mirror, and where given a positive longest box side in input pixels above which the view's boxes are
    dropped: an enlarged view kept for the small targets only)."""
    if isinstance(tta, bool):
        return TTA_VIEWS if tta else ()
    problem = (
        "tta must be true, false or a list of [scale, mirrored] or [scale, mirrored, max_side] views with a "
        f"positive scale, a true/false mirror and a positive max_side, got {tta!r}"
    )
    try:
        views = tuple(tuple(view) for view in tta)
    except TypeError as error:
        raise ValueError(problem) from error
    for view in views:
        if len(view) not in (2, 3) or not isinstance(view[1], bool):
            raise ValueError(problem)
        numbers = [view[0], *view[2:]]
        if any(isinstance(n, bool) or not isinstance(n, int | float) or not n > 0 for n in numbers):
            raise ValueError(problem)
    if not views:
        raise ValueError("tta: an empty list of views (false turns test-time augmentation off)")
    return views


def augmented_predictions(
    predict: Callable[[torch.Tensor], torch.Tensor],
    x: torch.Tensor,
    views: Sequence[tuple] = TTA_VIEWS,
) -> torch.Tensor:
    """Decoded predictions (B, N1 + N2 + ..., 5 + classes) float32 of `predict` (float images (B, 3, H, W) in
    [0, 1] -> decoded (B, N, 5 + classes), boxes as centre x, y, width, height in its input's pixels) over
    each (scale, mirrored) view of `x` (H and W multiples of 32): the view resized bilinearly to the
    multiple of 32 nearest `scale` times each side, mirrored left-right where asked, and its boxes mapped
    back to `x`'s pixels, so that one NMS takes the views' boxes together. A view given as (scale, mirrored,
    max_side) keeps only its boxes whose longer side is at most max_side of `x`'s pixels (the others get
    objectness 0)."""
    height, width = x.shape[2:]
    out = []
    for scale, mirrored, *max_side in views:
        if scale <= 0:
            raise ValueError(f"a test-time augmentation scale must be positive, got {scale}")
        size = tuple(max(STRIDE, round(side * scale / STRIDE) * STRIDE) for side in (height, width))
        view = (
            x
            if size == (height, width)
            else F.interpolate(x, size=size, mode="bilinear", align_corners=False)
        )
        # a float32 copy: mapped in place without touching the model's own output (or a bfloat16 one)
        pred = predict(torch.flip(view, dims=[3]) if mirrored else view).to(torch.float32, copy=True)
        if mirrored:
            pred[..., 0] = size[1] - pred[..., 0]
        pred[..., [0, 2]] *= width / size[1]
        pred[..., [1, 3]] *= height / size[0]
        if max_side:
            pred[..., 4] *= pred[..., 2:4].amax(dim=-1) <= max_side[0]
        out.append(pred)
    return torch.cat(out, dim=1)


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
    augment: bool = False,
) -> list[np.ndarray]:
    """Per RGB uint8 (H, W, 3) frame an (n, 6) float array `x1, y1, x2, y2, score, class` (xyxy pixels
    of that frame, clipped to it; boxes with no area left out), best score first. `model` is a `YOLOv5`
    in eval mode (or anything with its `predict`); frames of one call share a size. `augment`: with
    test-time augmentation (`TTA_VIEWS`).
    """
    prepared = [network_input(frame, image_size) for frame in frames]
    device = next(iter(model.parameters()), torch.zeros(())).device
    x = torch.from_numpy(np.stack([p[0] for p in prepared])).to(device).permute(0, 3, 1, 2).float() / 255
    predictions = augmented_predictions(model.predict, x) if augment else model.predict(x)
    return frame_detections(
        predictions.float(),
        prepared,
        [frame.shape for frame in frames],
        conf_threshold=conf_threshold,
        iou_threshold=iou_threshold,
        max_det=max_det,
    )
