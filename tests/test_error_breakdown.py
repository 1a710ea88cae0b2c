"""The error breakdown sorts each false positive and miss by what lies under it, after the score's own
matching, and tabulates them per scenario."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest

from spacetrack.config import REPO_ROOT
from spacetrack.evaluation import evaluate

spec = importlib.util.spec_from_file_location(
    "error_breakdown", REPO_ROOT / "experiments/detector_cv/error_breakdown.py"
)
eb = importlib.util.module_from_spec(spec)
spec.loader.exec_module(eb)


def write_mot(path, rows):
    np.savetxt(path, rows, fmt="%g", delimiter=",")


def gt_row(frame, tid, x, y, w, h, visibility=1.0):
    return [frame, tid, x, y, w, h, 1, 0, visibility]


def hyp_row(frame, tid, x, y, w, h):
    return [frame, tid, x, y, w, h, 1, -1, -1, -1]


# frame 1: target 1 boxed by a part only (a 10x10 box inside its 40x40), target 2 boxed loosely (shifted
# by half its width: IoU 1/3), target 3 matched, and a box on nothing.
# frame 2: target 1 matched, plus its part beside it; target 2 with no box at all.
GT = np.array(
    [
        gt_row(1, 1, 0, 0, 40, 40), gt_row(1, 2, 100, 0, 20, 20), gt_row(1, 3, 200, 200, 30, 30),
        gt_row(2, 1, 0, 0, 40, 40), gt_row(2, 2, 100, 0, 20, 20),
    ],
    dtype=float,
)  # fmt: skip
HYP = np.array(
    [
        hyp_row(1, 7, 5, 5, 10, 10), hyp_row(1, 8, 110, 0, 20, 20), hyp_row(1, 9, 201, 201, 30, 30),
        hyp_row(1, 10, 400, 400, 8, 8),
        hyp_row(2, 11, 0, 0, 40, 40), hyp_row(2, 7, 5, 5, 10, 10),
    ],
    dtype=float,
)  # fmt: skip


def test_breakdown_sorts_false_positives_and_misses():
    counts = eb.breakdown(GT, HYP)
    assert {k: counts[k] for k in eb.FP_KINDS} == {"part": 2, "loose": 1, "elsewhere": 1}
    assert {k: counts[k] for k in eb.FN_KINDS} == {"part_boxed": 1, "loosely_boxed": 1, "unboxed": 1}
    assert counts["matches"] == 2 and counts["switches"] == 0
    # the same false positives and misses as the score
    scores = evaluate({"s": (GT, HYP)})["s"]
    assert sum(counts[k] for k in eb.FP_KINDS) == scores["fp"]
    assert sum(counts[k] for k in eb.FN_KINDS) == scores["fn"]


def test_a_stricter_inside_share_turns_parts_loose():
    # half of this box lies inside target 1: a part at inside 0.5, loose at 0.8
    hyp = np.array([hyp_row(1, 1, 35, 0, 10, 10)], dtype=float)
    gt = GT[:1]
    assert eb.breakdown(gt, hyp, inside=0.5)["part"] == 1
    assert eb.breakdown(gt, hyp, inside=0.8)["loose"] == 1
    with pytest.raises(ValueError, match="inside must lie in"):
        eb.breakdown(gt, hyp, inside=0.0)


def test_tables_per_scenario_from_results_on_disk(tmp_path):
    data, results = tmp_path / "data", tmp_path / "results"
    for seq in ("seq_001_dim", "seq_002_nominal"):
        (data / seq / "gt").mkdir(parents=True)
        write_mot(data / seq / "gt" / "gt.txt", GT)
        (results / "fold4").mkdir(parents=True, exist_ok=True)
        write_mot(results / "fold4" / f"{seq}.txt", HYP)
    found = {"gam_row": eb.name_counts(results, data)}
    assert set(found["gam_row"][4]) == {"seq_001_dim", "seq_002_nominal"}
    by_manifest = {"seq_001_dim": "dim", "seq_002_nominal": "nominal"}
    out = eb.write_tables(found, tmp_path / "study", inside=0.8, scenario_of=by_manifest)
    text = out.read_text()
    assert "| dim | 1 | 2 | 2 | 1 | 1 | 1 | 1 | 1 | 0 |" in text
    assert "| all | 2 | 4 | 4 | 2 | 2 | 2 | 2 | 2 | 0 |" in text
    assert (
        json.loads((tmp_path / "study" / "errors.json").read_text())["gam_row"]["4"]["seq_001_dim"]["part"]
        == 2
    )


def test_a_result_without_ground_truth_is_a_clear_error(tmp_path):
    (tmp_path / "results" / "fold0").mkdir(parents=True)
    write_mot(tmp_path / "results" / "fold0" / "seq_009_dim.txt", HYP)
    with pytest.raises(SystemExit, match="seq_009_dim.txt: no ground truth"):
        eb.name_counts(tmp_path / "results", tmp_path / "data")


def test_unboxed_misses_are_counted_by_target_size_and_age(tmp_path):
    # one 40 px target (id 1) present frames 1-12, boxed only in frame 12; one 10 px target (id 2) that
    # appears in frame 11 and is never boxed
    gt = np.array(
        [gt_row(f, 1, 0, 0, 40, 20) for f in range(1, 13)]
        + [gt_row(f, 2, 100, 100, 10, 6) for f in (11, 12)],
        dtype=float,
    )
    hyp = np.array([hyp_row(12, 5, 0, 0, 40, 20)], dtype=float)
    counts = eb.breakdown(gt, hyp)
    assert counts["unboxed"] == 13
    assert {k: counts[k] for k in eb.UNBOXED_KINDS} == {
        "unboxed_lt16": 2,  # target 2 in frames 11 and 12
        "unboxed_16_32": 0,
        "unboxed_32_64": 11,  # target 1 in frames 1-11
        "unboxed_ge64": 0,
        "unboxed_early": 10 + 2,  # target 1's frames 1-10 and target 2's two frames
        "unboxed_gap": 0,  # neither was matched before
    }
    table = eb.write_tables({"row": {0: {"seq_001_dim": dict(counts)}}}, tmp_path, inside=0.8,
                            scenario_of={"seq_001_dim": "dim"})  # fmt: skip
    assert "| dim | 13 | 2 | 0 | 11 | 0 | 12 | 0 |" in table.read_text()


def test_unboxed_misses_just_after_a_match_are_gaps_in_a_live_track():
    # one 40 px target present frames 1-20, boxed on frames 1-8 and 15, unboxed on the rest
    gt = np.array([gt_row(f, 1, 0, 0, 40, 20) for f in range(1, 21)], dtype=float)
    hyp = np.array([hyp_row(f, 5, 0, 0, 40, 20) for f in (*range(1, 9), 15)], dtype=float)
    counts = eb.breakdown(gt, hyp)
    assert counts["unboxed"] == 11
    # frames 9-13 follow the match of frame 8 by 1-5 frames, 16-20 the one of frame 15; 14 is 6 after 8
    assert counts["unboxed_gap"] == 5 + 5


def test_scenarios_come_from_the_manifest_not_the_name(tmp_path):
    found = {"row": {0: {"clip_a": {"matches": 3}, "clip_b": {"matches": 1}}}}
    text = eb.write_tables(
        found, tmp_path, inside=0.8, scenario_of={"clip_a": "dim", "clip_b": "dim"}
    ).read_text()
    assert "| dim | 2 | 4 |" in text
    with pytest.raises(SystemExit, match="sequence clip_b is not in the dataset's manifest"):
        eb.write_tables(found, tmp_path, inside=0.8, scenario_of={"clip_a": "dim"})
