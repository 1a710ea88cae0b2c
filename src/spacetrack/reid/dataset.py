"""Re-ID training and evaluation crops from the rendered dataset: identity = (sequence, target id).

Rows come from `gt/gt.txt` (moving targets) and, with `include_static`, `gt/static.txt` (parked objects,
ids >= 1000): each is a distinct physical object, so it is one more identity to tell apart. Rows whose
visibility is below `min_visibility` (0 for fully hidden targets) or whose box is smaller than
`min_box_size` pixels on a side give no crop.

Every crop is cut once from its frame with `context` x the input size (the box's surroundings included)
and kept in memory as uint8; box jitter is then a random scale and shift of that larger crop followed by
a centre cut to the input size, which equals re-cropping the frame at a jittered box.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import albumentations as A
import cv2
import numpy as np
import torch
from torch.utils.data import Dataset

from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import BOX, CLASS, CONF, FRAME, ID, VISIBILITY, read_mot
from spacetrack.reid.crops import Cropper, frame_tensor


@dataclass(frozen=True)
class CropTable:
    """One row per crop: `identity` (0..K-1 over `names`), `sequence` (index into `sequences`), 1-based
    `frame`, `box` (N, 4) tlwh pixels, `visibility`, `object_class` (the row's class index); `names` holds
    each identity's (sequence, target id)."""

    sequences: list[str]
    names: list[tuple[str, int]]
    identity: np.ndarray
    sequence: np.ndarray
    frame: np.ndarray
    box: np.ndarray
    visibility: np.ndarray
    object_class: np.ndarray

    def __len__(self) -> int:
        return len(self.identity)


def collect_crops(
    root: str | Path,
    sequences: Sequence[str],
    *,
    min_visibility: float,
    min_box_size: float,
    include_static: bool,
    frame_stride: int = 1,
) -> CropTable:
    """The usable ground-truth rows of `sequences` (every `frame_stride`-th frame), identities numbered in
    order of (sequence, target id)."""
    if frame_stride < 1:
        raise ValueError(f"frame_stride must be >= 1, got {frame_stride}")
    files = ["gt.txt", "static.txt"] if include_static else ["gt.txt"]
    names: list[tuple[str, int]] = []
    parts = []
    for s, seq in enumerate(sequences):
        rows = [
            read_mot(Path(root) / seq / "gt" / f) for f in files if (Path(root) / seq / "gt" / f).is_file()
        ]
        if not rows:
            raise FileNotFoundError(f"{Path(root) / seq / 'gt' / 'gt.txt'} not found (sequence {seq!r})")
        mot = np.concatenate(rows)
        keep = (
            ((mot[:, FRAME] - 1) % frame_stride == 0)
            & (mot[:, VISIBILITY] >= min_visibility)
            & (mot[:, CONF] > 0)
            & (mot[:, BOX][:, 2:].min(axis=1) >= min_box_size)
        )
        mot = mot[keep]
        ids = np.unique(mot[:, ID]).astype(int)
        label = np.searchsorted(ids, mot[:, ID].astype(int)) + len(names)
        names += [(seq, int(i)) for i in ids]
        columns = (mot[:, FRAME].astype(int), mot[:, BOX], mot[:, VISIBILITY], mot[:, CLASS].astype(int))
        parts.append((label, np.full(len(mot), s), *columns))
    if not names:
        raise ValueError(
            f"no usable crops in {root} for {len(sequences)} sequences (min_visibility={min_visibility}, "
            f"min_box_size={min_box_size})"
        )
    cols = [np.concatenate(c) for c in zip(*parts, strict=True)]
    return CropTable(list(sequences), names, *cols)


def cut_crops(
    root: str | Path, table: CropTable, cropper: Cropper, *, scale: float = 1.0, image_dir: str = "img"
) -> np.ndarray:
    """uint8 (N, H, W, 3) RGB crops for every row of `table`, H, W = `scale` x the input size. Frames are
    read from the dataset's decoded-frame cache (`FrameStore`, shared with the detector training), so
    the nine folds' trainings decode each frame once between them."""
    h, w = round(cropper.height * scale), round(cropper.width * scale)
    out = np.zeros((len(table), h, w, 3), dtype=np.uint8)
    store = FrameStore(root=root, image_dir=image_dir)
    store.prepare(table.sequences)
    for s, seq in enumerate(table.sequences):
        frames = store.frames(seq)
        in_seq = np.flatnonzero(table.sequence == s)
        for f in np.unique(table.frame[in_seq]):
            rows = in_seq[table.frame[in_seq] == f]
            if f > len(frames):
                raise ValueError(
                    f"{Path(root) / seq}: ground truth names frame {f}, only {len(frames)} images"
                )
            crops = cropper(frame_tensor(np.array(frames[f - 1])), table.box[rows], scale)
            out[rows] = (crops.permute(0, 2, 3, 1) * 255).round().clamp_(0, 255).byte().numpy()
    return out


def jitter_augment(
    *,
    height: int,
    width: int,
    jitter_scale: float,
    jitter_shift: float,
    brightness: float,
    flip: float,
    blur: float,
) -> A.Compose:
    """Box jitter (scale +- `jitter_scale`, shift +- `jitter_shift` of the crop size), then a centre cut to
    height x width, horizontal flips, brightness/contrast (+- `brightness`), motion blur and sensor noise."""
    return A.Compose(
        [
            A.Affine(
                scale=(1 - jitter_scale, 1 + jitter_scale),
                translate_percent=(-jitter_shift, jitter_shift),
                border_mode=cv2.BORDER_CONSTANT,
                fill=0,
                p=1.0,
            ),
            A.CenterCrop(height, width),
            A.HorizontalFlip(p=flip),
            A.RandomBrightnessContrast(brightness_limit=brightness, contrast_limit=brightness, p=0.8),
            A.MotionBlur(blur_limit=(3, 7), p=blur),
            A.GaussNoise(std_range=(0.01, 0.05), p=0.3),
        ]
    )


class CropDataset(Dataset):
    """(crop float32 (3, height, width) in [0, 1], identity) pairs from cached uint8 crops.

    Crops larger than height x width are centre-cut (after `augment`, when given). Augmentation is seeded by
    (seed, epoch, index), so an epoch is the same whatever the number of workers.
    """

    def __init__(
        self,
        crops: np.ndarray,
        labels: np.ndarray,
        *,
        height: int,
        width: int,
        augment: A.Compose | None = None,
        seed: int = 0,
    ) -> None:
        if len(crops) != len(labels):
            raise ValueError(f"{len(crops)} crops but {len(labels)} labels")
        self.crops, self.labels = crops, np.asarray(labels, dtype=np.int64)
        self.height, self.width, self.augment, self.seed = height, width, augment, seed
        self.epoch = 0

    def __len__(self) -> int:
        return len(self.crops)

    def __getitem__(self, index: int) -> tuple[torch.Tensor, int]:
        image = self.crops[index]
        if self.augment is not None:
            seed = np.random.SeedSequence([self.seed, self.epoch, index]).generate_state(1)[0]
            self.augment.set_random_seed(int(seed))
            image = self.augment(image=image)["image"]
        top, left = (image.shape[0] - self.height) // 2, (image.shape[1] - self.width) // 2
        image = image[top : top + self.height, left : left + self.width]
        return torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float().div(255.0), int(
            self.labels[index]
        )
