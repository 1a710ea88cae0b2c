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


class BrightBlob(torch.nn.Module):
    """Predicts one box framing the pixels brighter than half in its input (class 0, objectness 0.9):
    where a view sees the target, and how large, in that view's pixels."""

    def predict(self, x):
        rows = []
        for image in x[:, 0]:
            ys, xs = torch.nonzero(image > 0.5, as_tuple=True)
            x1, y1, x2, y2 = xs.min(), ys.min(), xs.max() + 1, ys.max() + 1
            rows.append(torch.tensor([[(x1 + x2) / 2, (y1 + y2) / 2, x2 - x1, y2 - y1, 0.9, 1.0]]))
        return torch.stack(rows).float()


def test_every_augmented_view_maps_its_box_back_to_the_input_pixels():
    from spacetrack.engine.inference import TTA_VIEWS, augmented_predictions

    x = torch.zeros(2, 3, 480, 640)
    x[0, :, 96:108, 196:208] = 1.0  # a 12x12 target centred at (202, 102)
    x[1, :, 396:408, 36:48] = 1.0  # and at (42, 402)
    pred = augmented_predictions(BrightBlob().predict, x)
    assert pred.shape == (2, len(TTA_VIEWS), 6)  # one box per view, all together for one NMS
    # the mirrored and shrunken views see it elsewhere and smaller in their own pixels; mapped back, the
    # same box within a pixel or two of resampling (the 0.83 view is 384x512, the 0.67 one 320x416)
    np.testing.assert_allclose(pred[0, :, :4].numpy(), [[202, 102, 12, 12]] * 3, atol=2.0)
    np.testing.assert_allclose(pred[1, :, :4].numpy(), [[42, 402, 12, 12]] * 3, atol=2.0)
    mirrored = augmented_predictions(BrightBlob().predict, x, views=[(1.0, True)])
    assert mirrored[0, 0, :4].tolist() == [202, 102, 12, 12]  # exact: no resampling
    with pytest.raises(ValueError, match="scale must be positive, got 0"):
        augmented_predictions(BrightBlob().predict, x, views=[(0, False)])


def test_detect_with_test_time_augmentation_keeps_one_box_for_the_views_agreeing():
    frame = np.zeros((480, 640, 3), dtype=np.uint8)
    frame[96:108, 196:208] = 255
    (plain,) = detect(BrightBlob(), [frame])
    (augmented,) = detect(BrightBlob(), [frame], augment=True)
    assert len(plain) == 1 and len(augmented) == 1  # the three views' boxes overlap: NMS keeps one
    assert augmented[0, :4] == pytest.approx(plain[0, :4], abs=2.0)
