"""HOTA through TrackEval on sequences whose scores are worked out by hand.

HOTA at one localisation threshold alpha is sqrt(DetA * AssA) with DetA = TP / (TP + FN + FP) and AssA
the mean over true positives c of |TPA(c)| / (|TPA(c)| + |FNA(c)| + |FPA(c)|): of the matches between
c's ground-truth id and c's result id, over those ids' matches and misses (Luiten et al., 2021). The
reported score is the mean over alpha = 0.05, 0.10, ..., 0.95 (19 values).
"""

import numpy as np
import pytest

from spacetrack.evaluation import OVERALL, evaluate


def _mot(rows):
    """(frame, id, x, y, w, h) tuples -> (N, 9) MOT rows, conf 1, class and visibility unknown."""
    out = np.array(rows, dtype=float).reshape(-1, 6)
    return np.hstack([out, np.tile([1.0, -1.0, -1.0], (len(out), 1))])


GT = _mot([(f, 1, 10 + f, 20, 10, 10) for f in range(1, 11)])  # one target over ten frames


def test_one_perfect_track_scores_one():
    m = evaluate({"s": (GT, GT.copy())})["s"]
    assert m["hota"] == pytest.approx(1.0)
    assert m["deta"] == pytest.approx(1.0)
    assert m["assa"] == pytest.approx(1.0)
    assert m["loca"] == pytest.approx(1.0)


def test_an_identity_switch_halfway_halves_assa():
    # Result id 7 on frames 1-5, id 8 on frames 6-10, boxes exact: every alpha has TP 10, FN 0, FP 0,
    # so DetA = 1. A true positive of id 7: TPA 5 (gt 1 - result 7 matches), FNA 5 (gt 1's frames 6-10,
    # matched to another id), FPA 0 -> 5 / (5 + 5 + 0) = 0.5; the same for id 8, so AssA = 0.5 and
    # HOTA = sqrt(1 * 0.5) = 0.7071. MOTA counts it as a single switch: 1 - 1/10 = 0.9.
    hyp = GT.copy()
    hyp[5:, 1] = 8
    hyp[:5, 1] = 7
    m = evaluate({"s": (GT, hyp)})["s"]
    assert m["deta"] == pytest.approx(1.0)
    assert m["assa"] == pytest.approx(0.5)
    assert m["hota"] == pytest.approx(np.sqrt(0.5))
    assert m["mota"] == pytest.approx(0.9)


def test_loose_boxes_count_only_below_their_iou():
    # Result boxes 16 wide around the 10 x 10 target: IoU 100 / 160 = 0.625. They match at the 12
    # thresholds alpha <= 0.60 (HOTA 1 there) and at none of the 7 above (TP 0: DetA = AssA = 0),
    # so HOTA = DetA = AssA = 12 / 19; LocA, the mean IoU of matches at each alpha that has any,
    # is 0.625 there and TrackEval's 1 at the others: (12 * 0.625 + 7) / 19.
    hyp = GT.copy()
    hyp[:, 4] = 16
    m = evaluate({"s": (GT, hyp)})["s"]
    assert m["hota"] == pytest.approx(12 / 19)
    assert m["deta"] == pytest.approx(12 / 19)
    assert m["assa"] == pytest.approx(12 / 19)
    assert m["loca"] == pytest.approx((12 * 0.625 + 7) / 19)


def test_overall_pools_true_positives_across_sequences():
    # perfect (10 TP, AssA 1) + switched (10 TP, AssA 0.5): AssA = (10 * 1 + 10 * 0.5) / 20 = 0.75,
    # DetA = 20 / 20 = 1, HOTA = sqrt(0.75).
    switched = GT.copy()
    switched[5:, 1] = 2
    m = evaluate({"perfect": (GT, GT.copy()), "switched": (GT, switched)})[OVERALL]
    assert m["assa"] == pytest.approx(0.75)
    assert m["hota"] == pytest.approx(np.sqrt(0.75))


def test_misses_false_positives_and_ignored_rows():
    # Results on frames 1-5 only, plus one stray box on frame 1: TP 5, FN 5, FP 1 -> DetA = 5 / 11;
    # the five matches are all of result id 1's, and gt 1 has 10 rows: AssA = 5 / (5 + 5 + 0) = 0.5.
    hyp = np.vstack([GT[:5], _mot([(1, 9, 200, 200, 10, 10)])])
    m = evaluate({"s": (GT, hyp)})["s"]
    assert m["deta"] == pytest.approx(5 / 11)
    assert m["assa"] == pytest.approx(0.5)
    # A fully hidden row (conf 0) is neither a miss nor, when a result covers it, a false positive.
    hidden = GT.copy()
    hidden[5:, 6] = 0
    m = evaluate({"s": (hidden, GT.copy())})["s"]
    assert (m["hota"], m["fp"], m["fn"]) == (pytest.approx(1.0), 0, 0)


def test_no_result_at_all_scores_zero():
    m = evaluate({"s": (GT, _mot([]))})["s"]
    assert (m["hota"], m["deta"], m["assa"]) == (0.0, 0.0, 0.0)
