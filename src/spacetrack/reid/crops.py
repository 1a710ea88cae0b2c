"""How a box becomes a network input: a fixed-aspect sampling box, bilinear sampling, batched, on any device.

Boxes come in `tlwh` (top-left x, y, width, height; pixels; 0-based, covering columns x..x+w-1). The
sampling box is the box grown by `margin` of its size on every side, then brought to the input aspect
(width/height = 64/128 for Table 1) by one of three rules:

- `contain` (default): grow the short side about the centre until the aspect matches. The whole target is
  kept and undistorted; a wide target (spread solar arrays) fills less of the crop's height, a slender one
  less of its width. Our targets turn, so their aspect swings frame to frame, and only this rule keeps the
  same physical pixels in view at every aspect.
- `truncate`: the original DeepSORT rule, width := height x aspect about the centre. Wide targets lose their
  sides (the arrays), which are what tells one satellite from another.
- `stretch`: resample the box to the input size whatever its aspect; the target's shape is distorted
  differently as it turns.

Pixels are sampled with `torchvision.ops.roi_align` (bilinear, averaging ceil(box/out) samples per output
pixel so large boxes are anti-aliased); sample points outside the frame read as 0, black like the sky, so
boxes partly or wholly outside the frame need no special case. Boxes thinner than `min_size` pixels are
widened to it about their centre (a zero-area box still gives a crop).
"""

from __future__ import annotations

import numpy as np
import torch
from torchvision.ops import roi_align

CROP_MODES = ("contain", "truncate", "stretch")


def check_frame(frame: np.ndarray) -> None:
    """Raise a ValueError unless `frame` is an RGB uint8 (H, W, 3) array."""
    if not isinstance(frame, np.ndarray) or frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype != np.uint8:
        shape = getattr(frame, "shape", None)
        raise ValueError(f"frame must be an RGB uint8 (H, W, 3) array, got {type(frame).__name__} {shape}")


def check_boxes(boxes_tlwh: np.ndarray | list) -> np.ndarray:
    """`boxes_tlwh` as an (N, 4) float64 array; any other shape or a non-finite value is a ValueError."""
    boxes = np.asarray(boxes_tlwh, dtype=np.float64)
    if boxes.size == 0:
        return np.zeros((0, 4))
    if boxes.ndim != 2 or boxes.shape[1] != 4:
        raise ValueError(f"boxes must be an (N, 4) tlwh array, got shape {boxes.shape}")
    bad = np.flatnonzero(~np.isfinite(boxes).all(axis=1))
    if bad.size:
        raise ValueError(f"box {bad[0]} is not finite: {boxes[bad[0]].tolist()} (tlwh)")
    return boxes


def frame_tensor(frame: np.ndarray, device: torch.device | str = "cpu") -> torch.Tensor:
    """RGB uint8 (H, W, 3) -> float32 (3, H, W) in [0, 1] on `device`."""
    check_frame(frame)
    return torch.from_numpy(np.ascontiguousarray(frame)).to(device).permute(2, 0, 1).float().div_(255.0)


class Cropper:
    """Turns `tlwh` boxes of a frame into (N, 3, height, width) crops (floats in [0, 1])."""

    def __init__(
        self,
        *,
        height: int = 128,
        width: int = 64,
        mode: str = "contain",
        margin: float = 0.1,
        min_size: float = 1.0,
    ) -> None:
        if mode not in CROP_MODES:
            raise ValueError(f"crop mode {mode!r} is not one of {CROP_MODES}")
        if margin < 0 or min_size <= 0 or height <= 0 or width <= 0:
            raise ValueError(
                f"crop needs positive height, width and min_size and margin >= 0, got "
                f"height={height} width={width} min_size={min_size} margin={margin}"
            )
        self.height, self.width, self.mode = int(height), int(width), mode
        self.margin, self.min_size = float(margin), float(min_size)

    def sampling_boxes(self, boxes_tlwh: np.ndarray | list, scale: float = 1.0) -> np.ndarray:
        """(N, 4) `xyxy` regions (continuous pixel coordinates) sampled for each box; `scale` > 1 takes more
        context about the same centre (a crop of `scale` x the input size shows the input crop in its middle)."""
        boxes = check_boxes(boxes_tlwh)
        w = np.maximum(boxes[:, 2], self.min_size) * (1 + 2 * self.margin)
        h = np.maximum(boxes[:, 3], self.min_size) * (1 + 2 * self.margin)
        cx, cy = boxes[:, 0] + boxes[:, 2] / 2, boxes[:, 1] + boxes[:, 3] / 2
        aspect = self.width / self.height
        if self.mode == "contain":
            w, h = np.maximum(w, h * aspect), np.maximum(h, w / aspect)
        elif self.mode == "truncate":
            w = h * aspect
        half_w, half_h = w * scale / 2, h * scale / 2
        return np.stack([cx - half_w, cy - half_h, cx + half_w, cy + half_h], axis=1)

    def __call__(
        self, frame: torch.Tensor, boxes_tlwh: np.ndarray | list, scale: float = 1.0
    ) -> torch.Tensor:
        """Crops of `frame` ((3, H, W) float, see `frame_tensor`) at `boxes_tlwh`, shape
        (N, 3, round(height x scale), round(width x scale)), on the frame's device."""
        regions = torch.as_tensor(
            self.sampling_boxes(boxes_tlwh, scale), dtype=frame.dtype, device=frame.device
        )
        rois = torch.cat([regions.new_zeros(len(regions), 1), regions], dim=1)
        size = (round(self.height * scale), round(self.width * scale))
        return roi_align(frame[None], rois, size, spatial_scale=1.0, sampling_ratio=-1, aligned=True)
