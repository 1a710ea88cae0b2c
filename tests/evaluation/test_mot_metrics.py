from pathlib import Path

import motmetrics
import numpy as np
import pytest

from spacetrack.data.layout import read_mot
from spacetrack.evaluation import OVERALL, evaluate

TUD = Path(motmetrics.__file__).parent / "data"
# motmetrics' published values for its bundled TUD files (its tests/test_metrics.py), in the order
# IDF1, IDP, IDR, recall, precision, GT ids, MT, PT, ML, FP, FN, IDSW, FRAG, MOTA, MOTP (1 - IoU).
PUBLISHED = {
    "TUD-Campus": [
        0.557659,
        0.729730,
        0.451253,
        0.582173,
        0.941441,
        8,
        1,
        6,
        1,
        13,
        150,
        7,
        7,
        0.526462,
        0.277201,
    ],
    "TUD-Stadtmitte": [
        0.644619,
        0.819760,
        0.531142,
        0.608997,
        0.939920,
        10,
        5,
        4,
        1,
        45,
        452,
        7,
        6,
        0.564014,
        0.345904,
    ],
    OVERALL: [
        0.624296,
        0.799176,
        0.512211,
        0.602640,
        0.940268,
        18,
        6,
        10,
        2,
        58,
        602,
        14,
        13,
        0.555116,
        0.330177,
    ],
}
KEYS = [
    "idf1",
    "idp",
    "idr",
    "recall",
    "precision",
    "num_gt_ids",
    "mt",
    "pt",
    "ml",
    "fp",
    "fn",
    "idsw",
    "frag",
]


def test_reproduces_motmetrics_published_tud_values():
    names = ["TUD-Campus", "TUD-Stadtmitte"]
    results = evaluate({n: (read_mot(TUD / n / "gt.txt"), read_mot(TUD / n / "test.txt")) for n in names})
    for name, expected in PUBLISHED.items():
        got = [results[name][k] for k in KEYS] + [results[name]["mota"], 1 - results[name]["motp"]]
        np.testing.assert_allclose(got, expected, atol=1e-3, err_msg=name)


def _mot(rows):
    """rows of (frame, id, x, y, w, h[, conf, class, visibility]) -> (N, 9) with defaults 1, 0, 1."""
    out = np.tile([0, 0, 0, 0, 0, 0, 1.0, 0.0, 1.0], (len(rows), 1))
    for i, r in enumerate(rows):
        out[i, : len(r)] = r
    return out


def test_hand_worked_mota():
    # 3 frames, 2 targets. Frame 1: both matched. Frame 2: target 2 missed, one hypothesis far away
    # (FP). Frame 3: target 1 taken over by hypothesis 12 (IDSW), target 2 matched.
    gt = _mot([(f, k, 100 * k, 0, 20, 20) for f in (1, 2, 3) for k in (1, 2)])
    hyp = _mot(
        [(1, 11, 100, 0, 20, 20), (1, 12, 200, 0, 20, 20)]
        + [(2, 11, 101, 0, 20, 20), (2, 13, 500, 500, 20, 20)]
        + [(3, 12, 100, 0, 20, 20), (3, 14, 200, 0, 20, 20)]
    )
    m = evaluate({"s": (gt, hyp)})["s"]
    assert (m["fp"], m["fn"], m["idsw"]) == (1, 1, 2)  # target 2 also changes from 12 to 14
    assert m["mota"] == pytest.approx(1 - (1 + 1 + 2) / 6)
    assert m["motp"] == pytest.approx((4 + 19 * 20 / (2 * 400 - 19 * 20)) / 5)  # mean IoU of 5 matches


def test_pooled_motp_leaves_out_sequences_without_a_match():
    gt = _mot([(f, 1, 10, 10, 20, 20) for f in (1, 2, 3)])
    hyp = _mot([(1, 5, 10, 10, 20, 20), (2, 5, 12, 10, 20, 20)])  # IoU 1 and 18 * 20 / (2 * 400 - 360)
    out = evaluate({"tracked": (gt, hyp), "missed": (gt, _mot([])), "more": (gt, hyp)})
    assert np.isnan(out["missed"]["motp"])
    assert out[OVERALL]["motp"] == pytest.approx(out["tracked"]["motp"])
    assert out["tracked"]["motp"] == pytest.approx((1 + 360 / 440) / 2)
    assert out[OVERALL]["fn"] == 1 + 3 + 1


def test_iou_threshold_is_inclusive_at_one_half():
    gt = _mot([(1, 1, 0, 0, 30, 10)])
    at_half = _mot([(1, 5, 10, 0, 30, 10)])  # IoU 20 / 40 = 0.5
    below = _mot([(1, 5, 11, 0, 30, 10)])
    assert evaluate({"s": (gt, at_half)})["s"]["fp"] == 0
    assert evaluate({"s": (gt, below)})["s"]["fp"] == 1


def test_hidden_ground_truth_is_ignored_and_so_are_hypotheses_on_it():
    # target 2 is fully hidden in frame 2 (conf 0); a hypothesis there is neither FP nor TP
    gt = _mot([(1, 1, 0, 0, 20, 20), (1, 2, 100, 0, 20, 20), (2, 1, 0, 0, 20, 20), (2, 2, 100, 0, 20, 20, 0)])
    hyp = _mot([(1, 7, 0, 0, 20, 20), (1, 8, 100, 0, 20, 20), (2, 7, 0, 0, 20, 20), (2, 8, 100, 0, 20, 20)])
    m = evaluate({"s": (gt, hyp)})["s"]
    assert (m["fp"], m["fn"], m["mota"]) == (0, 0, 1.0)  # merely dropping the row would make it an FP
    hyp_without = hyp[:3]
    assert evaluate({"s": (gt, hyp_without)})["s"]["fn"] == 0  # and keeping it would make this a miss


def test_min_visibility_ignores_barely_visible_targets():
    gt = _mot([(1, 1, 0, 0, 20, 20, 1, 0, 0.1), (1, 2, 100, 0, 20, 20, 1, 0, 0.9)])
    hyp = _mot([(1, 8, 100, 0, 20, 20)])
    assert evaluate({"s": (gt, hyp)})["s"]["fn"] == 1
    assert evaluate({"s": (gt, hyp)}, min_visibility=0.5)["s"]["fn"] == 0


def test_reader_names_file_line_and_value(tmp_path):
    path = tmp_path / "res.txt"
    path.write_text("1,1,0,0,10,10,1,-1,-1,-1\n2,1,0,zero,10,10\n")
    with pytest.raises(ValueError, match=r"res.txt: line 2 is not numeric: '2,1,0,zero,10,10'"):
        read_mot(path)
    path.write_text("1,1,0,0\n")
    with pytest.raises(ValueError, match="line 1 has 4 columns"):
        read_mot(path)
    path.write_text("1,1,0,nan,10,10\n")
    with pytest.raises(ValueError, match="line 1 holds a NaN"):
        read_mot(path)
    path.write_text("")
    assert read_mot(path).shape == (0, 9)


def test_scoring_keeps_the_log_clean(caplog):
    caplog.set_level("INFO")
    evaluate({"s": (_mot([(1, 1, 0, 0, 20, 20)]), _mot([(1, 5, 0, 0, 20, 20)]))})
    assert "seconds" not in caplog.text  # motmetrics' timing messages


def test_class_accuracy_of_matched_boxes_by_track_vote_and_by_frame():
    from spacetrack.evaluation.mot import class_accuracy, named_matches

    # target 1 (class 1) over 4 frames; target 2 (class 0) on frames 1-2; one result box off every target
    gt = np.array([[f, 1, 10 * f, 0, 10, 10, 1, 1, 1.0] for f in range(1, 5)]
                  + [[f, 2, 100, 100, 10, 10, 1, 0, 1.0] for f in (1, 2)])  # fmt: skip
    hyp = np.array([[f, 5, 10 * f, 0, 10, 10, 1, -1, -1, -1] for f in range(1, 5)]
                   + [[1, 6, 100, 100, 10, 10, 1, -1, -1, -1], [2, 6, 300, 300, 10, 10, 1, -1, -1, -1]])  # fmt: skip
    # per result row: its own detection's class (-1: coasting), its track's vote
    classes = np.array([[1, 1], [2, 1], [-1, 1], [1, 1], [2, 2], [0, 2]])
    named = named_matches(gt, hyp, classes)
    assert sorted(named.tolist()) == [[0, 2, 2], [1, -1, 1], [1, 1, 1], [1, 1, 1], [1, 2, 1]]
    matching = {}
    evaluate({"s": (gt, hyp)}, accumulators=matching)  # the evaluator's own matching, not made again
    assert sorted(named_matches(gt, hyp, classes, matching=matching["s"]).tolist()) == sorted(named.tolist())
    scores = class_accuracy(named)
    assert scores["class_accuracy"] == pytest.approx(4 / 5)  # track 6 is named debris: wrong
    assert scores["class_accuracy_frame"] == pytest.approx(2 / 4)  # the coasting box has no name of its own
    assert scores["class_matches"] == 5
    assert np.isnan(class_accuracy(np.zeros((0, 3)))["class_accuracy"])
