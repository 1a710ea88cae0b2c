"""The crop rules: aspect handling, margins, pixels beyond the frame, degenerate and bad boxes."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spacetrack.reid.crops import Cropper, frame_tensor


def aspect(region: np.ndarray) -> np.ndarray:
    return (region[:, 2] - region[:, 0]) / (region[:, 3] - region[:, 1])


def test_contain_keeps_the_whole_box_at_the_input_aspect() -> None:
    cropper = Cropper(mode="contain", margin=0.0)
    boxes = np.array([[10.0, 20.0, 100.0, 20.0], [0.0, 0.0, 10.0, 60.0]])  # wide array, slender body
    region = cropper.sampling_boxes(boxes)
    np.testing.assert_allclose(aspect(region), 0.5)
    assert (region[:, 0] <= boxes[:, 0]).all() and (region[:, 2] >= boxes[:, 0] + boxes[:, 2]).all()
    assert (region[:, 1] <= boxes[:, 1]).all() and (region[:, 3] >= boxes[:, 1] + boxes[:, 3]).all()
    np.testing.assert_allclose(region[0], [10.0, -70.0, 110.0, 130.0])  # height grown to 2 x width


def test_truncate_is_the_original_rule_and_cuts_wide_targets() -> None:
    region = Cropper(mode="truncate", margin=0.0).sampling_boxes([[10.0, 20.0, 100.0, 20.0]])
    np.testing.assert_allclose(region[0], [55.0, 20.0, 65.0, 40.0])  # width = height / 2 about the centre


def test_stretch_and_margin() -> None:
    region = Cropper(mode="stretch", margin=0.1).sampling_boxes([[10.0, 20.0, 100.0, 20.0]])
    np.testing.assert_allclose(region[0], [0.0, 18.0, 120.0, 42.0])
    wider = Cropper(mode="stretch", margin=0.1).sampling_boxes([[10.0, 20.0, 100.0, 20.0]], scale=2.0)
    np.testing.assert_allclose(wider[0], [-60.0, 6.0, 180.0, 54.0])


def test_crop_content_and_pixels_beyond_the_frame_are_black() -> None:
    frame = np.zeros((48, 64, 3), np.uint8)
    frame[:, :32] = (255, 0, 0)
    crops = Cropper(mode="stretch", margin=0.0)(frame_tensor(frame), [[0, 0, 32, 48], [-200, -200, 10, 10]])
    assert crops.shape == (2, 3, 128, 64)
    # red channel of the red half; the last column's bilinear samples reach a quarter into the black half
    torch.testing.assert_close(crops[0, 0, :, :-1], torch.ones(128, 63))
    torch.testing.assert_close(crops[0, 0, :, -1], torch.full((128,), 0.75))
    assert crops[0, 1:].abs().max() == 0
    assert crops[1].abs().max() == 0  # wholly outside: the sky


def test_partly_outside_box_keeps_its_inside_part() -> None:
    frame = np.full((48, 64, 3), 200, np.uint8)
    crop = Cropper(mode="stretch", margin=0.0)(frame_tensor(frame), [[48, 0, 32, 48]])[0]
    assert crop[:, :, :28].min() > 0.7  # the left half lies in the frame
    assert crop[:, :, 36:].max() == 0  # the right half lies beyond it


def test_zero_area_and_empty_boxes() -> None:
    frame = frame_tensor(np.zeros((20, 20, 3), np.uint8))
    cropper = Cropper(min_size=2.0, margin=0.0)
    region = cropper.sampling_boxes([[5.0, 5.0, 0.0, 0.0]])
    np.testing.assert_allclose(region[0], [4.0, 3.0, 6.0, 7.0])  # 2 x 2 px, then height doubled
    assert cropper(frame, [[5, 5, 0, 0]]).shape == (1, 3, 128, 64)
    assert cropper(frame, np.zeros((0, 4))).shape == (0, 3, 128, 64)
    assert cropper(frame, []).shape == (0, 3, 128, 64)


@pytest.mark.parametrize(
    ("boxes", "message"),
    [([[1, 2, 3]], r"\(N, 4\)"), ([[0, 0, 5, 5], [1, np.nan, 2, 2]], "box 1 is not finite")],
)
def test_bad_boxes(boxes, message) -> None:
    with pytest.raises(ValueError, match=message):
        Cropper().sampling_boxes(boxes)


def test_bad_settings_and_frames() -> None:
    with pytest.raises(ValueError, match="crop mode 'square'"):
        Cropper(mode="square")
    with pytest.raises(ValueError, match="RGB uint8"):
        frame_tensor(np.zeros((10, 10), np.uint8))
    with pytest.raises(ValueError, match="RGB uint8"):
        frame_tensor(np.zeros((10, 10, 3), np.float32))
