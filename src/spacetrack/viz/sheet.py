"""Contact sheets: many frames tiled into one RGB image, each with an optional caption; image files."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from spacetrack.io import atomic_path
from spacetrack.viz.draw import FONT, FONT_SCALE, check_rgb, draw_text

CAPTION_HEIGHT = 16  # pixels under each tile when labels are given
GAP_COLOR = (64, 64, 64)  # grey, so tiles of black space scenes stay apart


def contact_sheet(
    images: Sequence[np.ndarray],
    *,
    cols: int,
    labels: Sequence[str] | None = None,
    tile_width: int | None = None,
    gap: int = 2,
) -> np.ndarray:
    """Tile RGB uint8 `images` row by row into one RGB image, `cols` tiles wide (fewer if fewer images).

    Every tile is `tile_width` pixels wide (default: the first image's width) with the first image's
    aspect ratio; images are resized to it. With `labels`, a caption strip of CAPTION_HEIGHT pixels sits
    under each tile. Tiles are `gap` pixels apart. The sheet is
    `cols*tile_w + (cols-1)*gap` wide and `rows*(tile_h+caption) + (rows-1)*gap` high.
    """
    if len(images) == 0:
        raise ValueError("contact_sheet needs at least one image")
    if cols < 1:
        raise ValueError(f"cols must be at least 1, got {cols}")
    if labels is not None and len(labels) != len(images):
        raise ValueError(f"labels has {len(labels)} entries for {len(images)} images")
    for index, image in enumerate(images):
        check_rgb(image, f"image {index}")
    first_h, first_w = images[0].shape[:2]
    tile_w = int(tile_width or first_w)
    if tile_w < 1:
        raise ValueError(f"tile_width must be at least 1 pixel, got {tile_width}")
    tile_h = max(1, round(first_h * tile_w / first_w))
    caption = CAPTION_HEIGHT if labels is not None else 0
    cols = min(cols, len(images))
    rows = math.ceil(len(images) / cols)
    cell_w, cell_h = tile_w + gap, tile_h + caption + gap
    sheet = np.empty((rows * cell_h - gap, cols * cell_w - gap, 3), dtype=np.uint8)
    sheet[:] = GAP_COLOR
    for index, image in enumerate(images):
        top, left = (index // cols) * cell_h, (index % cols) * cell_w
        if image.shape[:2] != (tile_h, tile_w):
            # INTER_AREA keeps faint stars and thin targets visible when shrinking.
            image = cv2.resize(image, (tile_w, tile_h), interpolation=cv2.INTER_AREA)
        sheet[top : top + tile_h, left : left + tile_w] = image
        if labels is not None:
            strip = sheet[top + tile_h : top + tile_h + caption, left : left + tile_w]
            strip[:] = 0
            _, baseline = cv2.getTextSize(str(labels[index]), FONT, FONT_SCALE, 1)
            draw_text(strip, str(labels[index]), (2, caption - baseline), (255, 255, 255))
    return sheet


def encode_image(rgb: np.ndarray, ext: str, jpeg_quality: int = 90) -> bytes:
    """RGB uint8 to JPEG (`ext` "jpg") or PNG bytes (OpenCV's encoders are deterministic for the same
    input)."""
    params = [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality] if ext == "jpg" else [cv2.IMWRITE_PNG_COMPRESSION, 3]
    ok, buf = cv2.imencode(f".{ext}", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), params)
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {rgb.shape} image as {ext}")
    return buf.tobytes()


def write_image(path: str | Path, rgb: np.ndarray, *, jpeg_quality: int = 90) -> None:
    """Write an RGB uint8 image atomically, as JPEG or PNG by the file's suffix."""
    ext = Path(path).suffix.lower().lstrip(".")
    ext = "jpg" if ext == "jpeg" else ext
    if ext not in ("jpg", "png"):
        raise ValueError(f"{path}: images are written as .jpg or .png, not {Path(path).suffix!r}")
    data = encode_image(rgb, ext, jpeg_quality)
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
