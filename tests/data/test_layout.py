import cv2
import numpy as np
import pytest

from spacetrack.data.layout import read_mask, read_rgb


def test_images_are_read_as_rgb_and_masks_as_one_channel(tmp_path):
    rgb = np.zeros((4, 6, 3), np.uint8)
    rgb[..., 0] = 200  # red
    cv2.imwrite(str(tmp_path / "frame.png"), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(tmp_path / "mask.png"), np.full((4, 6), 255, np.uint8))
    assert np.array_equal(read_rgb(tmp_path / "frame.png"), rgb)
    assert read_mask(tmp_path / "mask.png").shape == (4, 6)


@pytest.mark.parametrize("read", [read_rgb, read_mask])
def test_a_missing_or_broken_image_is_an_error_naming_the_file(tmp_path, read):
    with pytest.raises(FileNotFoundError, match="nothing.png: image not found"):
        read(tmp_path / "nothing.png")
    (tmp_path / "empty.jpg").write_bytes(b"")
    with pytest.raises(ValueError, match="empty.jpg: cannot read image"):
        read(tmp_path / "empty.jpg")
