"""Detector data: whole frames and YOLO labels of the rendered dataset, at native size or letterboxed.

A sample is an RGB uint8 image and its labels as an (N, 5) array of rows `class, cx, cy, w, h`
normalised to that image: the frame at its own resolution padded on the right and bottom to a multiple
of 32 (`image_size=None`, how validation and inference see frames), or letterboxed to a square
(`image_size=S`, the whole-frame training of `train=full`). Training crops are in `data.crops`. Augmentation (albumentations: HSV jitter,
flips, scale/translate) is seeded by (seed, epoch, index), so an epoch is the same whatever the
number of workers and whether the run was resumed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from pathlib import Path

import albumentations as A
import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from spacetrack.data.exposure import DEFAULT_GAIN, Exposure, FrameExposure, exposure_probability
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import frame_paths, read_rgb

PAD_VALUE = 114
Enhancer = Callable[[np.ndarray], np.ndarray]


def read_labels(path: Path, num_classes: int) -> np.ndarray:
    """(N, 5) float32 rows `class cx cy w h` of a YOLO label file, checked line by line.

    A missing file is an error (the dataset writes an empty file for a frame without targets).
    """
    if not path.is_file():
        raise FileNotFoundError(f"label file {path} is missing (a frame without targets has an empty file)")
    rows = []
    for number, line in enumerate(path.read_text().splitlines(), start=1):
        if not line.strip():
            continue
        parts = line.split()
        if len(parts) != 5:
            raise ValueError(f"{path} line {number}: expected 5 values 'class cx cy w h', got {line!r}")
        try:
            cls, cx, cy, w, h = (float(v) for v in parts)
        except ValueError:
            raise ValueError(f"{path} line {number}: non-numeric value in {line!r}") from None
        if not cls.is_integer() or not 0 <= cls < num_classes:
            raise ValueError(f"{path} line {number}: class {parts[0]} is outside 0..{num_classes - 1}")
        if not (0 <= cx <= 1 and 0 <= cy <= 1 and 0 < w <= 1 and 0 < h <= 1):
            raise ValueError(
                f"{path} line {number}: box {parts[1:]} is not normalised (expected 0..1, w, h > 0)"
            )
        rows.append((cls, cx, cy, w, h))
    return np.array(rows, dtype=np.float32).reshape(-1, 5)


def letterbox(image: np.ndarray, size: int) -> tuple[np.ndarray, float, tuple[int, int]]:
    """Resize the longer side to `size` pixels and pad to size x size: (image, scale, (pad_x, pad_y))."""
    h, w = image.shape[:2]
    scale = size / max(h, w)
    new_w, new_h = round(w * scale), round(h * scale)
    if (new_w, new_h) != (w, h):
        interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
        image = cv2.resize(image, (new_w, new_h), interpolation=interpolation)
    pad_x, pad_y = (size - new_w) // 2, (size - new_h) // 2
    out = np.full((size, size, 3), PAD_VALUE, dtype=np.uint8)
    out[pad_y : pad_y + new_h, pad_x : pad_x + new_w] = image
    return out, scale, (pad_x, pad_y)


def letterbox_labels(
    labels: np.ndarray, shape: tuple[int, int], scale: float, pad: tuple[int, int], size: int
):
    """Labels normalised to an (H, W) image -> normalised to its size x size letterbox."""
    h, w = shape
    out = labels.copy()
    out[:, [1, 3]] = (labels[:, [1, 3]] * w * scale + np.array([pad[0], 0])) / size
    out[:, [2, 4]] = (labels[:, [2, 4]] * h * scale + np.array([pad[1], 0])) / size
    return out


def build_augmentation(
    *,
    hue: float,
    saturation: float,
    value: float,
    fliplr: float,
    flipud: float,
    scale: float,
    translate: float,
    fill: int = PAD_VALUE,
    exposure: float = 0.0,
    exposure_gain: Sequence[float] = DEFAULT_GAIN,
) -> A.Compose:
    """Re-exposure (probability, gain range: `spacetrack.data.exposure`), HSV jitter (albumentations shift
    limits), flips (probabilities), scale and translate (fractions); `fill` is the grey level of pixels the
    affine move brings in."""
    return A.Compose(
        [
            Exposure(gain=exposure_gain, p=exposure_probability(exposure)),
            A.HueSaturationValue(
                hue_shift_limit=hue, sat_shift_limit=saturation, val_shift_limit=value, p=0.5
            ),
            A.HorizontalFlip(p=fliplr),
            A.VerticalFlip(p=flipud),
            A.Affine(
                scale=(1 - scale, 1 + scale),
                translate_percent=(-translate, translate),
                fill=fill,
                p=0.5 if scale or translate else 0.0,
            ),
        ],
        bbox_params=A.BboxParams(format="yolo", label_fields=["classes"], clip=True, min_visibility=0.3),
    )


def pad_to_stride(image: np.ndarray, stride: int = 32, value: int = 0) -> np.ndarray:
    """`image` padded on the right and bottom so that its height and width are multiples of `stride`
    (returned as it is when they already are, as 640x480 frames are)."""
    h, w = image.shape[:2]
    ph, pw = -h % stride, -w % stride
    if not (ph or pw):
        return image
    return cv2.copyMakeBorder(image, 0, ph, 0, pw, cv2.BORDER_CONSTANT, value=(value,) * 3)


def image_source(root: Path, sequences: Sequence[str], enhancer_name: str) -> tuple[str, bool]:
    """(image folder, whether to enhance on the fly): a pre-enhanced `img_<name>` folder is preferred."""
    if enhancer_name == "none":
        return "img", False
    folder = f"img_{enhancer_name}"
    if all((root / seq / folder).is_dir() for seq in sequences):
        return folder, False
    return "img", True


def frame_samples(
    root: Path, sequences: Sequence[str], image_dir: str, frame_stride: int, num_classes: int
) -> list[tuple[str, int, Path, np.ndarray]]:
    """(sequence, 0-based frame index, image path, labels) of every `frame_stride`-th frame of each
    sequence, labels as read by `read_labels`."""
    samples = []
    for seq in sequences:
        for index, path in list(enumerate(frame_paths(root, seq, image_dir)))[::frame_stride]:
            labels = read_labels(root / seq / "labels" / f"{path.stem}.txt", num_classes)
            samples.append((seq, index, path, labels))
    if not samples:
        raise ValueError(f"no frames in {root} for sequences {list(sequences)}")
    return samples


class YoloDataset(Dataset):
    """Whole frames of `sequences` under `root` (every `frame_stride`-th).

    image_size: None keeps each frame's own resolution (padded to a multiple of 32 on the right and
        bottom); an integer letterboxes it to that square.
    store: decoded frames to read from (a `FrameStore`); None decodes each sample's file (and runs
        `enhancer` on it) when it is read.
    reexposure: re-exposes (and enhances) a frame before it is letterboxed, for an enhanced detector
        (`spacetrack.data.exposure.FrameExposure`); None reads every frame as stored.
    """

    def __init__(
        self,
        *,
        root: str | Path,
        sequences: Sequence[str],
        num_classes: int,
        image_size: int | None = None,
        image_dir: str = "img",
        enhancer: Enhancer | None = None,
        store: FrameStore | None = None,
        frame_stride: int = 1,
        augment: A.Compose | None = None,
        seed: int = 0,
        reexposure: FrameExposure | None = None,
    ) -> None:
        self.root = Path(root)
        self.image_size = image_size
        self.enhancer = enhancer
        self.store = store
        self.augment = augment
        self.reexposure = reexposure
        self.seed = seed
        self.epoch = 0
        image_dir = store.image_dir if store is not None else image_dir
        self.samples = frame_samples(self.root, sequences, image_dir, frame_stride, num_classes)
        if store is not None:
            store.prepare(sequences)

    def set_epoch(self, epoch: int) -> None:
        """Choose the augmentation draws of `epoch` (call before iterating a loader over this dataset)."""
        self.epoch = epoch

    def __len__(self) -> int:
        return len(self.samples)

    def image(self, index: int) -> np.ndarray:
        """The RGB uint8 frame of sample `index` as stored (enhanced when the dataset enhances)."""
        seq, frame, path, _ = self.samples[index]
        if self.store is not None:
            return np.asarray(self.store.frame(seq, frame))
        image = read_rgb(path)
        return image if self.enhancer is None else self.enhancer(image)

    def __getitem__(self, index: int) -> tuple[np.ndarray, np.ndarray]:
        seq, frame, _, labels = self.samples[index]
        image = None
        if self.reexposure is not None:
            image = self.reexposure(seq, frame, np.random.default_rng([self.seed, self.epoch, index]))
        if image is None:
            image = self.image(index)
        if self.image_size is None:
            boxed = pad_to_stride(image)
            scale = np.array([image.shape[1] / boxed.shape[1], image.shape[0] / boxed.shape[0]] * 2)
            labels = np.column_stack((labels[:, :1], labels[:, 1:] * scale)).astype(np.float32)
        else:
            boxed, scale, pad = letterbox(image, self.image_size)
            labels = letterbox_labels(labels, image.shape[:2], scale, pad, self.image_size)
        if self.augment is not None:
            boxed, labels = apply_augmentation(self.augment, boxed, labels, (self.seed, self.epoch, index))
        return boxed, labels


def apply_augmentation(
    augment: A.Compose, image: np.ndarray, labels: np.ndarray, key: Sequence[int]
) -> tuple[np.ndarray, np.ndarray]:
    """`augment` applied to an image and its normalised labels, its draws seeded by `key` (integers)."""
    seed = np.random.SeedSequence(list(key)).generate_state(1)[0]
    augment.set_random_seed(int(seed))
    out = augment(image=image, bboxes=labels[:, 1:], classes=labels[:, 0])
    labels = np.column_stack((out["classes"], out["bboxes"])).astype(np.float32).reshape(-1, 5)
    return out["image"], labels


def collate(batch: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[torch.Tensor, torch.Tensor]:
    """Images (B, 3, S, S) uint8 and targets (M, 6) rows `image_index, class, cx, cy, w, h` (normalised)."""
    images = torch.from_numpy(np.stack([img for img, _ in batch])).permute(0, 3, 1, 2).contiguous()
    targets = [
        np.column_stack((np.full(len(lab), i, dtype=np.float32), lab)) for i, (_, lab) in enumerate(batch)
    ]
    return images, torch.from_numpy(np.concatenate(targets).reshape(-1, 6))
