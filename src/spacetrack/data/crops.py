"""Detector training crops cut at native resolution from the decoded frames.

Targets are 3-156 px on 640x480 frames; shrinking a frame to fit a small network input removes the
small ones. Instead each sample is a `crop_size` x `crop_size` window of the frame at its own
resolution: most windows hold a target (a labelled box chosen at random, the window centred on it with
a random offset), the rest are drawn anywhere in the frame (mostly sky, stars, parked objects and
planet limbs: the hard negatives). With `mosaic` > 0 that fraction of samples are four half-size
windows of four frames tiled 2 x 2.

A sample is an RGB uint8 (crop_size, crop_size, 3) image and (N, 5) rows `class, cx, cy, w, h`
normalised to it, as `YoloDataset` gives, so both feed the same loader and loss. Every draw (window,
frames of a mosaic, augmentation) comes from (seed, epoch, index).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import albumentations as A
import numpy as np
from torch.utils.data import Dataset

from spacetrack.data.exposure import FrameExposure
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.yolo_dataset import apply_augmentation, frame_samples


def check_crop_size(crop_size: int, frame_shape: Sequence[int], where: str) -> None:
    """A crop is a multiple of 32 pixels (the network's largest stride) and fits inside every frame."""
    if crop_size <= 0 or crop_size % 32:
        raise ValueError(
            f"the crop size (train.image_size) must be a positive multiple of 32 pixels, got {crop_size}"
        )
    height, width = frame_shape[:2]
    if crop_size > min(height, width):
        raise ValueError(
            f"the crop size (train.image_size) {crop_size} is larger than the {width}x{height} frames of {where}"
        )


def window_labels(
    labels: np.ndarray, frame_shape: Sequence[int], x0: int, y0: int, size: int, min_visibility: float
) -> np.ndarray:
    """Labels normalised to a frame -> normalised to its window (x0, y0, size): boxes clipped to the
    window, kept when at least `min_visibility` of their area and 2 px each way remain."""
    height, width = frame_shape[:2]
    cx, cy, w, h = (labels[:, 1] * width, labels[:, 2] * height, labels[:, 3] * width, labels[:, 4] * height)
    x1, y1, x2, y2 = cx - w / 2 - x0, cy - h / 2 - y0, cx + w / 2 - x0, cy + h / 2 - y0
    cx1, cy1 = np.clip(x1, 0, size), np.clip(y1, 0, size)
    cx2, cy2 = np.clip(x2, 0, size), np.clip(y2, 0, size)
    area = np.maximum(w * h, 1e-9)
    inside = (cx2 - cx1) * (cy2 - cy1)
    keep = (inside >= min_visibility * area) & (cx2 - cx1 >= 2) & (cy2 - cy1 >= 2)
    boxes = np.column_stack(((cx1 + cx2) / 2, (cy1 + cy2) / 2, cx2 - cx1, cy2 - cy1)) / size
    return np.column_stack((labels[:, :1], boxes))[keep].astype(np.float32).reshape(-1, 5)


def pick_target(
    labels: np.ndarray, frame_shape: Sequence[int], small_bias: float, rng: np.random.Generator
) -> int:
    """The index of the target (of a frame's normalised `class, cx, cy, w, h` rows) a window centres on:
    any alike (`small_bias` 0), or each with weight side^-small_bias, side = sqrt(box area) in pixels."""
    if not small_bias:
        return int(rng.integers(len(labels)))
    height, width = frame_shape[:2]
    side = np.sqrt(np.maximum(labels[:, 3] * width * labels[:, 4] * height, 1.0))
    weight = side**-small_bias
    return int(rng.choice(len(labels), p=weight / weight.sum()))


class CropDataset(Dataset):
    """Native-resolution training windows of the frames of `sequences` (every `frame_stride`-th).

    store: the decoded frames (a `FrameStore` of the dataset at `root`).
    crop_size: window side in pixels (a multiple of 32, at most the frame's shorter side).
    background: fraction of windows drawn anywhere rather than on a target (0-1).
    jitter: how far a target may sit from the window centre, as a fraction of half the window (0-1).
    mosaic: fraction of samples made of four half-size windows of four frames (0-1).
    min_visibility: a box cut by the window edge is kept while this fraction of it is inside (0-1).
    small_bias: how much more often a window centres on a small target than on a large one of the same
        frame: a target is chosen with weight side^-small_bias, side the square root of its box area in
        pixels (0: every target alike; 1: a 10-px target five times as often as a 50-px one).
    reexposure: re-exposes (and enhances) a whole frame before its window is cut, for an enhanced
        detector (`spacetrack.data.exposure.FrameExposure`); None reads every frame from `store`.
    """

    def __init__(
        self,
        *,
        root: str | Path,
        sequences: Sequence[str],
        num_classes: int,
        store: FrameStore,
        crop_size: int = 256,
        frame_stride: int = 1,
        background: float = 0.2,
        jitter: float = 0.8,
        mosaic: float = 0.0,
        min_visibility: float = 0.4,
        small_bias: float = 0.0,
        augment: A.Compose | None = None,
        seed: int = 0,
        reexposure: FrameExposure | None = None,
    ) -> None:
        for name, value in (("background", background), ("jitter", jitter), ("mosaic", mosaic)):
            if not 0 <= value <= 1:
                raise ValueError(f"crops: {name} must lie in [0, 1], got {value}")
        if not 0 <= small_bias <= 4:
            raise ValueError(f"crops: small_bias must lie in [0, 4], got {small_bias}")
        self.samples = frame_samples(Path(root), sequences, store.image_dir, frame_stride, num_classes)
        store.prepare(sequences)
        self.store, self.crop_size = store, crop_size
        for seq in dict.fromkeys(s[0] for s in self.samples):
            check_crop_size(crop_size, store.frames(seq).shape[1:], f"sequence {seq} of {root}")
        if not any(len(s[3]) for s in self.samples):
            raise ValueError(f"no labelled target in the training frames of {root}: nothing to learn from")
        self.background, self.jitter, self.mosaic = background, jitter, mosaic
        self.min_visibility, self.augment, self.seed = min_visibility, augment, seed
        self.small_bias = small_bias
        self.reexposure = reexposure
        self.epoch = 0

    def set_epoch(self, epoch: int) -> None:
        """Choose the draws of `epoch` (call before iterating a loader over this dataset)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.samples)

    def window(self, index: int, size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        """A size x size window of sample `index`'s frame and its labels, placed by `rng`."""
        seq, frame, _, labels = self.samples[index]
        image = None if self.reexposure is None else self.reexposure(seq, frame, rng)
        if image is None:
            image = self.store.frame(seq, frame)
        height, width = image.shape[:2]
        if len(labels) and rng.random() >= self.background:
            _, cx, cy, _, _ = labels[pick_target(labels, (height, width), self.small_bias, rng)]
            offset = rng.uniform(-1, 1, size=2) * self.jitter * size / 2
            x0 = round(cx * width - size / 2 + offset[0])
            y0 = round(cy * height - size / 2 + offset[1])
        else:
            x0, y0 = rng.integers(width - size + 1), rng.integers(height - size + 1)
        x0, y0 = int(np.clip(x0, 0, width - size)), int(np.clip(y0, 0, height - size))
        crop = np.array(image[y0 : y0 + size, x0 : x0 + size])
        return crop, window_labels(labels, image.shape, x0, y0, size, self.min_visibility)

    def _mosaic(self, index: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
        half = self.crop_size // 2
        others = rng.integers(len(self.samples), size=3)
        image = np.zeros((self.crop_size, self.crop_size, 3), dtype=np.uint8)
        rows = []
        for k, i in enumerate((index, *others)):
            tile, labels = self.window(int(i), half, rng)
            oy, ox = divmod(k, 2)
            image[oy * half : (oy + 1) * half, ox * half : (ox + 1) * half] = tile
            labels[:, 1:] = labels[:, 1:] / 2 + np.array([ox, oy, 0, 0]) / 2
            rows.append(labels)
        return image, np.concatenate(rows)

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        rng = np.random.default_rng([self.seed, self.epoch, index])
        if self.mosaic and rng.random() < self.mosaic:
            image, labels = self._mosaic(index, rng)
        else:
            image, labels = self.window(index, self.crop_size, rng)
        if self.augment is not None:
            image, labels = apply_augmentation(self.augment, image, labels, (self.seed, self.epoch, index))
        return image, labels
