"""A hand-made two-sequence dataset in the on-disk layout: coloured rectangles as targets."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

FRAMES, H, W = 6, 96, 128
# target id -> (colour RGB, top-left at frame 1, size w x h, velocity px/frame)
TARGETS = {
    1: ((250, 40, 40), (10, 10), (24, 12), (3, 1)),
    2: ((40, 250, 40), (60, 40), (10, 20), (-2, 2)),
    3: ((60, 60, 250), (90, 70), (16, 16), (-3, -2)),
}
STATIC = {1000: ((200, 200, 200), (100, 5), (12, 8), (0, 0))}


def boxes_at(targets: dict, frame: int) -> dict[int, tuple[int, int, int, int]]:
    return {
        tid: (x + vx * (frame - 1), y + vy * (frame - 1), w, h)
        for tid, (_, (x, y), (w, h), (vx, vy)) in targets.items()
    }


def write_sequence(folder: Path, tint: int) -> None:
    (folder / "img").mkdir(parents=True)
    (folder / "gt").mkdir()
    gt, static = [], []
    for f in range(1, FRAMES + 1):
        image = np.zeros((H, W, 3), np.uint8)
        for targets, rows in ((STATIC, static), (TARGETS, gt)):
            for tid, (x, y, w, h) in boxes_at(targets, f).items():
                colour = np.clip(np.array(targets[tid][0]) - tint, 0, 255)
                image[y : y + h, x : x + w] = colour
                conf, vis = (0, 0.0) if (tid == 2 and f == 3) else (1, 0.2 if (tid == 3 and f == 5) else 1.0)
                rows.append(f"{f},{tid},{x},{y},{w},{h},{conf},0,{vis:.4f}")
        cv2.imwrite(str(folder / "img" / f"{f:06d}.jpg"), image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, 98])
    (folder / "gt" / "gt.txt").write_text("\n".join(gt) + "\n")
    (folder / "gt" / "static.txt").write_text("\n".join(static) + "\n")


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory) -> Path:
    """Two sequences (folds 0 and 1) of 6 frames at 128x96: targets 1-3 move, 1000 is static; target 2 is
    hidden (conf 0) in frame 3 and target 3 is 20 % visible in frame 5."""
    root = tmp_path_factory.mktemp("reid") / "tiny"
    names = ["seq_000_nominal", "seq_001_dim"]
    for i, name in enumerate(names):
        write_sequence(root / name, tint=30 * i)
    sequences = [
        {"name": n, "scenario": n[8:], "fold": i, "num_frames": FRAMES, "width": W, "height": H}
        for i, n in enumerate(names)
    ]
    manifest = {
        "name": "tiny",
        "format_version": 1,
        "num_folds": 2,
        "image_ext": "jpg",
        "sequences": sequences,
        "content_hash": "sha256:tiny",
    }
    (root / "manifest.json").write_text(json.dumps(manifest))
    return root
