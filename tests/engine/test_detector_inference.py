import numpy as np
import pytest
import torch

from spacetrack.engine.inference import detect


class FixedBox(torch.nn.Module):
    """Predicts one box, given in letterbox pixels as (cx, cy, w, h), with objectness 0.9."""

    def __init__(self, cxcywh):
        super().__init__()
        self.row = torch.tensor([[*cxcywh, 0.9, 1.0]])

    def predict(self, x):
        return self.row.expand(len(x), 1, 6)


def test_boxes_come_back_in_frame_pixels():
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    # 640x480 -> 320x240 at scale 0.5, padded by 40 rows on top: letterbox box (100, 90)-(120, 110).
    (det,) = detect(FixedBox((110, 100, 20, 20)), [frame], image_size=320)
    assert det[:, :4].tolist() == [[200.0, 100.0, 240.0, 140.0]]
    assert det[0, 4] == pytest.approx(0.9)


def test_boxes_are_clipped_to_the_frame():
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    (det,) = detect(FixedBox((5, 45, 20, 20)), [frame, frame], image_size=320)[:1]
    assert det[0, :4].tolist() == [0.0, 0.0, 30.0, 30.0]


def test_boxes_left_with_no_area_are_dropped():
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    # Wholly in the top padding (rows 0-40 of the letterbox): clipped to the frame it has no height.
    (det,) = detect(FixedBox((110, 10, 20, 10)), [frame], image_size=320)
    assert det.shape == (0, 6)


def test_agnostic_nms_keeps_one_box_for_a_target_named_two_ways():
    from spacetrack.engine.nms import non_max_suppression

    # two anchors on one target (IoU 0.82): one calls it class 0 (score 0.72), the other class 1 (0.56);
    # a third box elsewhere
    pred = torch.tensor([[
        [50.0, 50.0, 20.0, 20.0, 0.9, 0.8, 0.2],
        [51.0, 50.0, 20.0, 20.0, 0.8, 0.3, 0.7],
        [150.0, 50.0, 20.0, 20.0, 0.9, 0.9, 0.1],
    ]])  # fmt: skip
    per_class = non_max_suppression(pred, conf_threshold=0.1, iou_threshold=0.45)[0]
    agnostic = non_max_suppression(pred, conf_threshold=0.1, iou_threshold=0.45, agnostic=True)[0]
    assert len(per_class) == 3 and sorted(per_class[:, 5].tolist()) == [0.0, 0.0, 1.0]
    assert len(agnostic) == 2 and agnostic[:, 5].tolist() == [0.0, 0.0]  # the best-scored name of each
    assert agnostic[:, 4].tolist() == pytest.approx([0.81, 0.72])
