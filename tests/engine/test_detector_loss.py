import math

import pytest
import torch

from spacetrack.engine.boxes import ciou
from spacetrack.engine.loss import YoloLoss
from spacetrack.models.yolo import COCO_ANCHORS

SIZE = 640
STRIDES = torch.tensor([8.0, 16.0, 32.0])


def make_loss(num_classes: int = 1, **kwargs) -> YoloLoss:
    anchors = torch.tensor(COCO_ANCHORS).view(3, 3, 2)
    return YoloLoss(anchors=anchors, strides=STRIDES, num_classes=num_classes, image_size=SIZE, **kwargs)


def zero_outputs(num_classes: int = 1, batch: int = 1) -> list[torch.Tensor]:
    return [torch.zeros(batch, 3, SIZE // s, SIZE // s, 5 + num_classes) for s in (8, 16, 32)]


def anchor_sized_target(cx_cells: float, cy_cells: float) -> torch.Tensor:
    """A 10x13-pixel target (the smallest anchor) centred at the given stride-8 grid position."""
    return torch.tensor([[0, 0, cx_cells * 8 / SIZE, cy_cells * 8 / SIZE, 10 / SIZE, 13 / SIZE]])


def test_target_at_a_cell_centre_goes_to_its_cell_and_the_anchors_within_ratio_four():
    levels = make_loss().assign(zero_outputs(), anchor_sized_target(10.5, 20.5))
    b, a, gj, gi, tbox, anchor, tcls = levels[0]
    # Anchors 16x30 and 33x23 are within a factor 4 of 10x13 in both sides; the stride-16/32 ones are not.
    assert sorted(a.tolist()) == [0, 1, 2]
    assert set(gi.tolist()) == {10} and set(gj.tolist()) == {20}
    assert torch.allclose(tbox[:, :2], torch.full((3, 2), 0.5))
    assert all(len(level[0]) == 0 for level in levels[1:])


def test_target_off_centre_also_uses_the_two_nearest_neighbour_cells():
    b, a, gj, gi, *_ = make_loss().assign(zero_outputs(), anchor_sized_target(10.3, 20.8))[0]
    cells = set(zip(gi.tolist(), gj.tolist(), strict=True))
    # Nearer the left edge (x frac 0.3) and the bottom edge (y frac 0.8).
    assert cells == {(10, 20), (9, 20), (10, 21)}
    assert len(a) == 9


def test_loss_on_a_hand_built_target():
    loss_fn = make_loss()
    total, (lbox, lobj, lcls) = loss_fn(zero_outputs(batch=2), anchor_sized_target(10.5, 20.5))

    # Zero logits predict each anchor's own box at the cell centre: concentric boxes, no centre term.
    def expected_ciou(w: float, h: float) -> float:
        inter = min(w, 10) * min(h, 13)
        iou = inter / (w * h + 130 - inter)
        v = 4 / math.pi**2 * (math.atan(10 / 13) - math.atan(w / h)) ** 2
        return iou - (v * v / (v - iou + 1) if v else 0.0)

    ious = [expected_ciou(10, 13), expected_ciou(16, 30), expected_ciou(33, 23)]
    assert ious[0] == pytest.approx(1.0)
    assert lbox.item() == pytest.approx(0.05 * sum(1 - i for i in ious) / 3, rel=1e-4)
    # Logit 0 gives BCE log(2) whatever the target; levels weighted 4, 1, 0.4.
    assert lobj.item() == pytest.approx(math.log(2) * 5.4, rel=1e-5)
    assert lcls.item() == 0.0
    assert total.item() == pytest.approx(2 * (lbox + lobj).item(), rel=1e-6)


def test_class_loss_and_gradients_flow():
    loss_fn = make_loss(num_classes=3)
    raw = [p.requires_grad_() for p in zero_outputs(num_classes=3)]
    targets = anchor_sized_target(10.5, 20.5)
    targets[0, 1] = 2
    total, components = loss_fn(raw, targets)
    assert components[2] > 0
    total.backward()
    assert raw[0].grad[0, 0, 20, 10, 7] < 0  # raise the logit of the true class
    assert raw[0].grad[0, 0, 20, 10, 5] > 0


def test_ciou_is_one_for_identical_boxes_and_penalises_distance():
    box = torch.tensor([[50.0, 50.0, 20.0, 10.0]])
    assert ciou(box, box).item() == pytest.approx(1.0, abs=1e-6)
    far = torch.tensor([[150.0, 50.0, 20.0, 10.0]])
    assert ciou(box, far).item() < 0


def test_iou_ratio_sets_the_objectness_target_of_matched_anchors():
    """With iou_ratio 0 every matched anchor learns objectness 1 whatever its box; with 1, its IoU. For
    confident predictions (objectness logit 4 everywhere) the first target is nearer, so its loss is lower."""
    raw = zero_outputs(num_classes=3)
    for p in raw:
        p[..., 4] = 4.0
    targets = torch.tensor([[0, 1, 0.5, 0.5, 0.2, 0.3]])
    _, by_iou = make_loss(3, iou_ratio=1.0)(raw, targets)
    _, by_one = make_loss(3, iou_ratio=0.0)(raw, targets)
    assert by_iou[0] == by_one[0] and by_iou[2] == by_one[2]  # box and class terms do not change
    assert by_one[1] < by_iou[1]
    with pytest.raises(ValueError, match="iou_ratio must lie in"):
        make_loss(3, iou_ratio=1.5)


def test_a_stride_4_level_gets_its_own_balance_and_learns_small_targets():
    from spacetrack.models.yolo import P2_ANCHORS

    anchors = torch.tensor([*COCO_ANCHORS, P2_ANCHORS]).view(4, 3, 2)
    strides = torch.tensor([8.0, 16.0, 32.0, 4.0])
    loss = YoloLoss(anchors=anchors, strides=strides, num_classes=1, image_size=SIZE, balance_p2=16.0)
    assert loss.balance == [4.0, 1.0, 0.4, 16.0]
    with pytest.raises(ValueError, match="balance has 2 entries for 4 detection levels"):
        YoloLoss(anchors=anchors, strides=strides, num_classes=1, image_size=SIZE, balance=(4.0, 1.0))
    outputs = [torch.zeros(1, 3, SIZE // s, SIZE // s, 6) for s in (8, 16, 32, 4)]
    levels = loss.assign(outputs, anchor_sized_target(10.5, 20.5))
    b, a, gj, gi, *_ = levels[3]  # the 10x13 target also matches the stride-4 anchors, at its finer cell
    assert len(b) > 0 and set(gi.tolist()) >= {21} and set(gj.tolist()) >= {41}
