import numpy as np
import pytest

from spacetrack.motion.blobs import Blob, find_blobs
from spacetrack.motion.dynamic import DynamicFilter, coverage, overlap_min_area


def test_find_blobs_centroid_box_and_area():
    mask = np.zeros((20, 30), np.uint8)
    mask[2:5, 4:7] = 255  # 3x3: the outline through pixel centres encloses 4 px²
    mask[10, 20] = 255
    blobs = find_blobs(mask)
    big = next(b for b in blobs if b.area > 0)
    assert big.tlwh == (4, 2, 3, 3) and big.area == 4.0 and big.centroid == pytest.approx((5.0, 3.0))
    assert len(blobs) == 2
    assert find_blobs(mask, min_area=1) == [big]


def test_overlap_is_over_the_smaller_box_and_coverage_over_the_first():
    others = [[2, 2, 2, 2], [8, 0, 10, 10], [50, 50, 1, 1]]
    np.testing.assert_allclose(overlap_min_area([[0, 0, 10, 10]], others), [[1.0, 0.2, 0.0]])
    np.testing.assert_allclose(coverage([[0, 0, 10, 10]], others), [[0.04, 0.2, 0.0]])


def test_boxes_with_a_blob_are_dynamic_and_the_others_static():
    blobs = [Blob((15.0, 15.0), (10, 10, 10, 10), 90.0), Blob((103.0, 50.0), (101, 48, 4, 4), 9.0)]
    boxes = np.array(
        [
            [12, 12, 10, 10],  # overlaps the first blob
            [90, 40, 12, 20],  # no overlap but the second blob's centroid is 7 px from its centre
            [300, 300, 20, 20],  # a parked satellite: no blob anywhere near
        ]
    )
    assert DynamicFilter(min_overlap=0.3, max_distance=8.0)(boxes, blobs).tolist() == [True, True, False]
    assert DynamicFilter(min_overlap=0.3, max_distance=0.0)(boxes, blobs).tolist() == [True, False, False]
    assert not DynamicFilter()(boxes, []).any()


def test_a_large_static_box_crossed_by_a_small_blob_stays_static():
    planet = np.array([[0, 200, 400, 280]])
    crossing = [Blob((100.0, 300.0), (95, 295, 10, 10), 81.0)]
    assert not DynamicFilter(min_coverage=0.1)(planet, crossing).any()
    assert DynamicFilter(min_coverage=0.0)(planet, crossing).all()


def test_select_keeps_the_rows_of_moving_detections():
    detections = np.zeros((2, 12))
    detections[:, 2:6] = [[12, 12, 10, 10], [300, 300, 20, 20]]
    detections[:, 0] = 7
    kept = DynamicFilter().select(detections, [Blob((15.0, 15.0), (10, 10, 10, 10), 90.0)])
    np.testing.assert_array_equal(kept, detections[:1])


def test_bad_thresholds():
    with pytest.raises(ValueError, match="min_overlap"):
        DynamicFilter(min_overlap=0)
    with pytest.raises(ValueError, match="min_coverage"):
        DynamicFilter(min_coverage=1.5)
    with pytest.raises(ValueError, match="max_distance"):
        DynamicFilter(max_distance=-1)


def test_a_blob_marks_only_boxes_near_its_best_iou_with_min_share_of_best():
    # A mover (29x61) passes in front of a parked object (20x24): its blob covers the parked box too.
    blob = Blob((130.0, 190.0), (116, 160, 29, 61), 1700.0)
    boxes = np.array([[117, 160, 29, 61], [113, 160, 20, 24]], float)  # the mover, the parked object
    assert DynamicFilter()(boxes, [blob]).tolist() == [True, True]  # the paper's test
    assert DynamicFilter(min_share_of_best=0.5)(boxes, [blob]).tolist() == [True, False]
    # two movers side by side in one blob: both near its best IoU, both marked
    pair = np.array([[100, 100, 10, 10], [111, 100, 10, 10]], float)
    merged = Blob((110.5, 105.0), (100, 100, 21, 10), 200.0)
    assert DynamicFilter(min_share_of_best=0.5)(pair, [merged]).tolist() == [True, True]
    with pytest.raises(ValueError, match="min_share_of_best"):
        DynamicFilter(min_share_of_best=1.5)
