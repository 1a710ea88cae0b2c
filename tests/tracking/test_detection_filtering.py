import numpy as np

from spacetrack.tracking.preprocessing import filter_detections, non_max_suppression


def test_nms_overlap_is_intersection_over_the_other_box_area_not_iou():
    big = [0, 0, 99, 99]  # 100 x 100 px with the +1 convention
    small = [10, 10, 19, 19]  # fully inside: IoU 0.01, but it is 100% covered
    # big scores higher: small is covered by 1.0 > 0.5 -> suppressed although IoU is tiny
    np.testing.assert_array_equal(non_max_suppression(np.array([big, small]), np.array([0.9, 0.8]), 0.5), [0])
    # small scores higher: big is covered by 400 / 10000 = 0.04 -> kept, highest score first
    np.testing.assert_array_equal(
        non_max_suppression(np.array([big, small]), np.array([0.8, 0.9]), 0.5), [1, 0]
    )


def test_nms_at_overlap_one_only_sorts_by_confidence():
    boxes = np.array([[0, 0, 10, 10]] * 3, dtype=float)
    np.testing.assert_array_equal(non_max_suppression(boxes, np.array([0.5, 0.9, 0.7]), 1.0), [1, 2, 0])


def test_filter_drops_low_confidence_and_short_boxes_then_suppresses():
    tlwh = np.array([[0, 0, 10, 10], [1, 1, 10, 10], [50, 50, 10, 10], [80, 80, 10, 3]], dtype=float)
    confidence = np.array([0.9, 0.8, 0.2, 0.95])
    kept = filter_detections(
        tlwh, confidence, min_confidence=0.3, nms_max_overlap=0.5, min_detection_height=5
    )
    np.testing.assert_array_equal(kept, [0])
