"""Tiny datasets and models for the detector tests."""

import json
from pathlib import Path

import cv2
import numpy as np

from spacetrack.engine.loss import YoloLoss
from spacetrack.models.yolo import YOLOv5

WIDTH, HEIGHT, FRAMES = 64, 48, 4


def write_tiny_dataset(root: Path, num_folds: int = 9) -> Path:
    """One sequence per fold, each a bright 10x8 box moving right on a dark sky, in the dataset layout."""
    sequences = []
    for fold in range(num_folds):
        name = f"seq_{fold:03d}_nominal"
        for sub in ("img", "labels"):
            (root / name / sub).mkdir(parents=True)
        for frame in range(1, FRAMES + 1):
            image = np.full((HEIGHT, WIDTH, 3), 5, dtype=np.uint8)
            x, y = 8 + 6 * frame + fold, 12 + 2 * fold
            image[y : y + 8, x : x + 10] = (200, 220, 240)
            cv2.imwrite(str(root / name / "img" / f"{frame:06d}.jpg"), image)
            label = (
                f"{fold % 3} {(x + 5) / WIDTH:.6f} {(y + 4) / HEIGHT:.6f} {10 / WIDTH:.6f} {8 / HEIGHT:.6f}\n"
            )
            (root / name / "labels" / f"{frame:06d}.txt").write_text(label)
        sequences.append(
            {"name": name, "scenario": "nominal", "fold": fold, "num_frames": FRAMES, "width": WIDTH,
             "height": HEIGHT, "fps": 10, "seed": fold, "num_targets": 1}
        )  # fmt: skip
    manifest = {
        "name": root.name,
        "format_version": 1,
        "class_names": ["satellite", "rocket_body", "debris"],
        "num_folds": num_folds,
        "image_ext": "jpg",
        "image_dirs": ["img"],
        "sequences": sequences,
        "counts": {},
        "config": {},
        "content_hash": "sha256:0",
    }
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root


def tiny_model(**kwargs) -> YOLOv5:
    """A narrow YOLOv5 (width 1/8 of YOLOv5l) that trains in well under a second per step."""
    return YOLOv5(num_classes=3, depth_multiple=0.33, width_multiple=0.125, **kwargs)


def loss_for(model: YOLOv5, image_size: int) -> YoloLoss:
    return YoloLoss(anchors=model.detect.anchors, strides=model.stride, num_classes=3, image_size=image_size)
