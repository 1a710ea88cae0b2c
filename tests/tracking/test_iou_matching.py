import numpy as np

from spacetrack.tracking.iou_matching import intersections, iou_matrix


def test_iou_by_hand():
    iou = iou_matrix([[0, 0, 10, 10]], [[5, 0, 10, 10], [20, 20, 2, 2], [0, 0, 10, 10]])
    np.testing.assert_allclose(iou, [[50 / 150, 0.0, 1.0]])
    assert iou_matrix(np.zeros((0, 4)), [[0, 0, 1, 1]]).shape == (0, 1)


def test_empty_boxes_overlap_nothing():
    assert iou_matrix([[3, 3, 0, 0]], [[3, 3, 0, 0], [0, 0, 10, 10]]).tolist() == [[0.0, 0.0]]


def test_intersections_with_areas():
    inter, area_a, area_b = intersections([[0, 0, 4, 2]], [[2, 1, 4, 4], [10, 10, 1, 1]])
    assert inter.tolist() == [[2.0, 0.0]]
    assert area_a.tolist() == [8.0] and area_b.tolist() == [16.0, 1.0]
