"""The object-naming study: one object's truth rows, and what the best-overlapping detection calls it."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from spacetrack.config import REPO_ROOT

spec = importlib.util.spec_from_file_location(
    "object_names", REPO_ROOT / "experiments/naming/object_names.py"
)
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


def sequence(tmp_path):
    seq = tmp_path / "seq_000_dim"
    (seq / "gt").mkdir(parents=True)
    # frame, id, x, y, w, h, conf, class, visibility; object 2's second row is not labelled (conf 0)
    rows = [
        "1,1,5,5,4,4,1,0,0.9",
        "1,2,20,10,10,6,1,1,0.15",
        "2,2,22,10,10,6,0,1,0.0",
        "3,2,24,10,10,6,1,1,0.12",
    ]
    (seq / "gt" / "gt.txt").write_text("\n".join(rows) + "\n")
    return seq


def test_truth_rows_are_the_objects_labelled_rows_as_corner_boxes(tmp_path):
    sequence(tmp_path)
    rows = study.truth_rows(tmp_path, "seq_000_dim", 2)
    assert rows[:, 0].tolist() == [1, 3]  # frame 2 is not labelled
    assert rows[0, 1:5].tolist() == [20, 10, 30, 16] and rows[0, 5] == 1 and rows[1, 6] == pytest.approx(0.12)
    with pytest.raises(ValueError, match=r"seq_000_dim/gt/gt.txt: object 7 has no labelled row"):
        study.truth_rows(tmp_path, "seq_000_dim", 7)


def test_each_frame_counts_the_class_of_the_best_overlapping_detection_or_a_miss(tmp_path, monkeypatch):
    sequence(tmp_path)
    rows = study.truth_rows(tmp_path, "seq_000_dim", 2)
    answers = iter(
        [
            # frame 1: a debris box on it and a poorer rocket-body box beside it -> debris
            np.array([[20, 10, 30, 16, 0.4, 2], [26, 10, 36, 16, 0.9, 1]], dtype=float),
            # frame 3: only a box that overlaps it below IoU 0.45 -> missed
            np.array([[30, 10, 40, 16, 0.9, 1]], dtype=float),
        ]
    )
    monkeypatch.setattr(study, "detect", lambda model, frames, conf_threshold: [next(answers)])
    images = [np.zeros((32, 48, 3), np.uint8)] * len(rows)
    tally = study.names(None, images, rows[:, 1:5], ["satellite", "rocket_body", "debris"])
    assert tally == {"satellite": 0, "rocket_body": 0, "debris": 1, "missed": 1}
