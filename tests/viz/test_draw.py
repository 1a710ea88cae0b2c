"""Boxes and trails land on exactly the pixels asked for, in the colours asked for."""

from __future__ import annotations

import numpy as np
import pytest

from spacetrack.viz import draw_boxes, draw_trails, id_color

RED = (255, 0, 0)


def black(h: int = 60, w: int = 80) -> np.ndarray:
    return np.zeros((h, w, 3), dtype=np.uint8)


def perimeter(shape: tuple[int, int], x: int, y: int, w: int, h: int) -> np.ndarray:
    """Mask of the outermost pixels of the tlwh box (x, y, w, h)."""
    mask = np.zeros(shape, dtype=bool)
    mask[y, x : x + w] = mask[y + h - 1, x : x + w] = True
    mask[y : y + h, x] = mask[y : y + h, x + w - 1] = True
    return mask


def test_box_outline_is_the_perimeter_of_the_tlwh_box() -> None:
    frame = black()
    out = draw_boxes(frame, np.array([[10.0, 20.0, 30.0, 15.0]]), color=RED)
    expected = perimeter(frame.shape[:2], 10, 20, 30, 15)
    assert np.array_equal(out.any(axis=2), expected)
    assert np.all(out[expected] == RED)
    assert not frame.any(), "the input frame must not be drawn on"


def test_fractional_boxes_round_each_edge_to_the_nearest_pixel() -> None:
    # Columns round(9.6)=10 .. round(39.6)-1=39, rows round(20.4)=20 .. round(35.6)-1=35.
    out = draw_boxes(black(), [[9.6, 20.4, 30.0, 15.2]], color=RED)
    assert np.array_equal(out.any(axis=2), perimeter((60, 80), 10, 20, 30, 16))


def test_label_and_id_go_above_the_box_or_below_it_at_the_top_edge() -> None:
    out = draw_boxes(black(), [[10, 30, 30, 15]], labels=["sat"], ids=[7], color=RED)
    text_rows = np.nonzero((out.any(axis=2) & ~perimeter((60, 80), 10, 30, 30, 15)).any(axis=1))[0]
    assert len(text_rows) > 0 and text_rows.max() < 29

    out = draw_boxes(black(), [[10, 0, 30, 15]], ids=[7], color=RED)
    text_rows = np.nonzero((out.any(axis=2) & ~perimeter((60, 80), 10, 0, 30, 15)).any(axis=1))[0]
    assert len(text_rows) > 0 and text_rows.min() > 15


def test_color_by_id_gives_each_identity_its_own_stable_colour() -> None:
    boxes = [[5, 20, 10, 10], [40, 20, 10, 10]]
    out = draw_boxes(black(), boxes, ids=[1, 2], color_by_id=True)
    assert tuple(out[20, 5]) == id_color(1)
    assert tuple(out[20, 40]) == id_color(2)
    assert id_color(1) != id_color(2)
    assert id_color(1) == id_color(1)


def test_no_boxes_returns_an_unchanged_copy() -> None:
    frame = black()
    out = draw_boxes(frame, np.zeros((0, 4)))
    assert out is not frame and np.array_equal(out, frame)


@pytest.mark.parametrize(
    ("frame", "boxes", "kwargs", "message"),
    [
        (black(), [[1, 2, 3]], {}, r"\(N, 4\)"),
        (black(), [[1, 2, 3, 4]], {"labels": ["a", "b"]}, "labels has 2 entries for 1 boxes"),
        (black(), [[1, 2, 3, 4]], {"color_by_id": True}, "needs ids"),
        (black().astype(np.float32), [[1, 2, 3, 4]], {}, "RGB uint8"),
        (black()[:, :, 0], [[1, 2, 3, 4]], {}, "RGB uint8"),
    ],
)
def test_bad_input_is_a_clear_error(frame: np.ndarray, boxes: list, kwargs: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        draw_boxes(frame, boxes, **kwargs)


def test_trails_follow_the_centre_points_in_the_id_colour() -> None:
    out = draw_trails(black(), {3: [(10, 10), (50, 10)], 4: [(20, 40)]})
    assert np.all(out[10, 10:48] == id_color(3))
    assert not out[20:35].any(), "nothing between the two trails"
    assert tuple(out[40, 20]) == id_color(4)

    single = draw_trails(black(), {3: [(10, 10), (50, 10)]}, color=RED)
    assert tuple(single[10, 30]) == RED
