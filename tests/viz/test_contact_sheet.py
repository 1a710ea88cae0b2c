"""Contact sheet geometry: tile placement, gaps, captions and resizing."""

from __future__ import annotations

import numpy as np
import pytest

from spacetrack.viz import contact_sheet
from spacetrack.viz.sheet import CAPTION_HEIGHT, GAP_COLOR


def tiles(n: int, h: int = 30, w: int = 40) -> list[np.ndarray]:
    return [np.full((h, w, 3), 10 * (i + 1), dtype=np.uint8) for i in range(n)]


def test_tiles_sit_row_by_row_with_grey_gaps() -> None:
    sheet = contact_sheet(tiles(5), cols=3, gap=2)
    assert sheet.shape == (2 * 30 + 2, 3 * 40 + 2 * 2, 3)
    for i in range(5):
        top, left = (i // 3) * 32, (i % 3) * 42
        assert np.all(sheet[top : top + 30, left : left + 40] == 10 * (i + 1)), f"tile {i}"
    assert tuple(sheet[0, 40]) == GAP_COLOR
    assert tuple(sheet[30, 0]) == GAP_COLOR
    assert np.all(sheet[32:, 84:] == GAP_COLOR), "the sixth cell is empty"


def test_captions_and_tile_width_resize() -> None:
    sheet = contact_sheet(tiles(4), cols=2, labels=["a", "b", "c", "d"], tile_width=20, gap=0)
    tile_h = 15  # 30 * 20 / 40
    assert sheet.shape == (2 * (tile_h + CAPTION_HEIGHT), 2 * 20, 3)
    assert np.all(sheet[:tile_h, :20] == 10)
    assert np.all(sheet[:tile_h, 20:] == 20)
    caption = sheet[tile_h : tile_h + CAPTION_HEIGHT, :20]
    assert caption.max() > 128, "caption text is drawn in white"


def test_fewer_images_than_columns_gives_a_narrower_sheet() -> None:
    assert contact_sheet(tiles(2), cols=8, gap=0).shape == (30, 80, 3)


@pytest.mark.parametrize(
    ("images", "kwargs", "message"),
    [
        ([], {"cols": 2}, "at least one image"),
        (tiles(2), {"cols": 0}, "cols must be at least 1"),
        (tiles(2), {"cols": 2, "labels": ["a"]}, "labels has 1 entries for 2 images"),
        ([*tiles(1), np.zeros((30, 40), np.uint8)], {"cols": 2}, "image 1 must be RGB uint8"),
    ],
)
def test_bad_input_is_a_clear_error(images: list, kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        contact_sheet(images, **kwargs)


def test_write_image_writes_jpeg_or_png_by_suffix_and_refuses_others(tmp_path):
    import cv2

    from spacetrack.viz.sheet import write_image

    rgb = np.zeros((8, 10, 3), np.uint8)
    rgb[:, :, 0] = 200  # red
    for name in ("a.png", "b.jpg"):
        write_image(tmp_path / name, rgb)
        back = cv2.cvtColor(cv2.imread(str(tmp_path / name)), cv2.COLOR_BGR2RGB)
        assert back.shape == rgb.shape and abs(int(back[4, 5, 0]) - 200) <= 3 and back[4, 5, 2] <= 3
    with pytest.raises(ValueError, match=r"c\.bmp.*\.jpg or \.png"):
        write_image(tmp_path / "c.bmp", rgb)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.png", "b.jpg"]  # nothing half-written
