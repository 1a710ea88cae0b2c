"""The silhouette/seen-truth study adds Table 4 rows to a fold's piece only where they belong, keeps what the
piece holds, and sets the added rows beside the paper's in its table."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

from spacetrack.config import REPO_ROOT

spec = importlib.util.spec_from_file_location("seen_truth_study", REPO_ROOT / "experiments/seen_truth/run.py")
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


def metrics(mota: float) -> dict:
    return {"metrics": {"mota": mota, "fp": 1, "fn": 2}, "command": "...", "seconds": 1.0}


def piece(fold: int, variant: str, paper: float, gt: float) -> dict:
    own = study.ROWS[variant]
    return {
        "fold": fold,
        "variant": variant,
        "weights": f"w/{variant}_fold{fold}.pt",
        "trained_on": "seen",
        "detection": {},
        "tracking": {"silhouette": {}, "seen": {own[0]: metrics(paper), own[1]: metrics(gt)}},
    }


@pytest.fixture
def tracked(monkeypatch):
    """track_row records what it was asked to track and returns a fixed MOTA."""
    calls = []

    def track_row(row, fold, truth, weights, reid=None):
        calls.append((row, fold, truth, str(weights)) + ((str(reid),) if reid else ()))
        return metrics(0.61)

    monkeypatch.setattr(study, "track_row", track_row)
    return calls


def test_added_rows_are_tracked_against_the_detectors_own_truth_once(tracked):
    p = piece(2, "dwt_hsv_gam", 0.60, 0.91)
    p["tracking"]["seen"]["gt_deepsort_original"] = metrics(0.95)
    study.add_rows(p, ["gam_deepsort_original", "gt_deepsort_original"], Path("w/gam.pt"))
    # the row it already held is kept, not tracked again
    assert tracked == [("gam_deepsort_original", 2, "seen", "w/gam.pt")]
    assert p["tracking"]["seen"]["gam_deepsort_original"]["metrics"]["mota"] == 0.61
    assert p["tracking"]["seen"]["gt_deepsort_original"]["metrics"]["mota"] == 0.95
    assert p["tracking"]["silhouette"] == {}


@pytest.mark.parametrize("row", ["yolo_deepsort_original", "gam_no_such_row"])
def test_a_row_of_another_detector_or_no_row_is_refused_before_anything_is_tracked(tracked, row):
    p = piece(2, "dwt_hsv_gam", 0.60, 0.91)
    with pytest.raises(ValueError, match=f"--add-rows {row}: not a Table 4 row of dwt_hsv_gam"):
        study.add_rows(p, ["gam_deepsort_original", row], Path("w/gam.pt"))
    assert tracked == []
    assert "gam_deepsort_original" not in p["tracking"]["seen"]


def test_ordering_table_sets_the_added_rows_first_and_means_each_over_its_folds(tracked):
    with_original = piece(1, "dwt_hsv_gam", 0.70, 0.94)
    study.add_rows(with_original, ["gam_deepsort_original"], Path("w/gam.pt"))
    plain = piece(1, "yolov5s", 0.72, 0.94)
    without = piece(2, "dwt_hsv_gam", 0.60, 0.91)
    lines = study._ordering_section([plain, with_original, without])
    table = "\n".join(lines)
    assert (
        "| fold | gam_deepsort_original | yolo_deepsort_paper | gam_deepsort_paper | gt_deepsort_paper |"
        in table
    )
    # fold 2 has no added row: it is not listed
    assert "| 1 | 61.0 | 72.0 | 70.0 | 94.0 |" in table
    assert "| 2 |" not in table
    assert lines[-1] == "| mean (folds) | 61.0 (1) | 72.0 (1) | 70.0 (1) | 94.0 (1) |"
    # without any added row there is no such section
    assert study._ordering_section([plain, without]) == []


def study_driver(tmp_path: Path, monkeypatch, study, fold: int):
    """experiments/detector_cv/track_study.py with `study` for the seen-truth study, its study folders
    under `tmp_path`, and a detector of `fold` under `tmp_path/det`."""
    spec = importlib.util.spec_from_file_location(
        "detector_study_track", REPO_ROOT / "experiments/detector_cv/track_study.py"
    )
    driver = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(driver)
    monkeypatch.setattr(driver, "_seen_truth_study", lambda: study)
    monkeypatch.setattr(driver, "HERE", tmp_path)
    weights = tmp_path / "det" / f"yolov5s_fold{fold}" / "weights"
    weights.mkdir(parents=True)
    (weights / "best.pt").write_bytes(b"w")
    return driver


def test_the_study_tracking_driver_tracks_each_row_into_its_own_file_and_refuses_other_rows(
    tmp_path, monkeypatch
):
    calls = []

    class Study:
        @staticmethod
        def track_row(row, fold, truth, weights, out, experiment, extra, folder, data=None):
            assert extra == () and folder == row  # Table 4's row as it is, in its own folder
            calls.append((row, fold, truth, out, experiment))
            return metrics(0.7 if row.endswith("original") else 0.6)

    driver = study_driver(tmp_path, monkeypatch, Study, fold=2)
    detectors = tmp_path / "det"
    monkeypatch.setattr("sys.argv", ["track.py", "--study", "nowhere", "--folds", "2"])
    with pytest.raises(SystemExit, match="--study nowhere: .* is not a study folder"):
        driver.main()
    (tmp_path / "wider").mkdir()
    argv = ["track.py", "--study", "wider", "--folds", "2", "--detectors", str(detectors)]
    monkeypatch.setattr("sys.argv", argv)
    driver.main()
    assert [c[0] for c in calls] == ["yolo_deepsort_paper", "yolo_deepsort_original"]
    assert all(c[1:] == (2, "seen", "outputs/wider", "wider") for c in calls)
    piece = json.loads((tmp_path / "wider" / "tracking" / "yolo_deepsort_original_fold2.json").read_text())
    assert piece["row"] == "yolo_deepsort_original" and piece["metrics"]["mota"] == 0.7
    monkeypatch.setattr("sys.argv", argv + ["--rows", "sort_deepsort_paper"])
    with pytest.raises(SystemExit, match="not a Table 4 row on a study's detector boxes"):
        driver.main()
    # a gt_ row tracks the fold's ground-truth boxes: no detector, none needed
    calls.clear()
    monkeypatch.setattr("sys.argv", argv[:3] + ["--folds", "6", "--rows", "gt_deepsort_paper_frame"])
    driver.main()
    assert [c[:2] for c in calls] == [("gt_deepsort_paper_frame", 6)]
    piece = json.loads((tmp_path / "wider" / "tracking" / "gt_deepsort_paper_frame_fold6.json").read_text())
    assert piece["weights"] is None and piece["metrics"]["mota"] == 0.6
    monkeypatch.setattr("sys.argv", argv[:3] + ["--folds", "5", "--detectors", str(detectors)])
    with pytest.raises(SystemExit, match="yolov5s_fold5/weights/best.pt is missing"):
        driver.main()
    # a gam_ row tracks the study's YOLOv5s + GAM on DWT/HSV detector, refused before any row is tracked
    # while that detector is missing
    calls.clear()
    monkeypatch.setattr("sys.argv", argv + ["--rows", "yolo_deepsort_paper", "gam_deepsort_paper"])
    with pytest.raises(SystemExit, match="dwt_hsv_gam_fold2/weights/best.pt is missing"):
        driver.main()
    assert calls == []
    (detectors / "dwt_hsv_gam_fold2" / "weights").mkdir(parents=True)
    (detectors / "dwt_hsv_gam_fold2" / "weights" / "best.pt").write_bytes(b"g")
    driver.main()
    assert [c[0] for c in calls] == ["yolo_deepsort_paper", "gam_deepsort_paper"]
    piece = json.loads((tmp_path / "wider" / "tracking" / "gam_deepsort_paper_fold2.json").read_text())
    assert piece["weights"].endswith("dwt_hsv_gam_fold2/weights/best.pt")
    # --yolo-variant: the yolo_ rows track another variant's detector of the study
    monkeypatch.setattr("sys.argv", argv + ["--rows", "yolo_deepsort_paper", "--yolo-variant", "yolov5s_p2"])
    with pytest.raises(SystemExit, match="yolov5s_p2_fold2/weights/best.pt is missing"):
        driver.main()
    (detectors / "yolov5s_p2_fold2" / "weights").mkdir(parents=True)
    (detectors / "yolov5s_p2_fold2" / "weights" / "best.pt").write_bytes(b"p")
    driver.main()
    piece = json.loads((tmp_path / "wider" / "tracking" / "yolo_deepsort_paper_fold2.json").read_text())
    assert piece["weights"].endswith("yolov5s_p2_fold2/weights/best.pt")


def test_rows_tracked_with_the_folds_own_reid_are_kept_beside_the_shipped_ones(tracked, tmp_path):
    p = piece(5, "dwt_hsv_gam", 0.64, 0.93)
    with pytest.raises(ValueError, match="fold5/reid.pt is missing.*make train-reid FOLD=5"):
        study.add_rows(p, ["gam_deepsort_paper"], Path("w/gam.pt"), tmp_path)
    (tmp_path / "fold5").mkdir()
    (tmp_path / "fold5" / "reid.pt").write_bytes(b"r")
    study.add_rows(p, ["gam_deepsort_paper", "gt_deepsort_paper"], Path("w/gam.pt"), tmp_path)
    reid = str(tmp_path / "fold5" / "reid.pt")
    assert tracked == [
        ("gam_deepsort_paper", 5, "seen", "w/gam.pt", reid),
        ("gt_deepsort_paper", 5, "seen", "w/gam.pt", reid),
    ]
    rows = p["tracking"]["seen"]
    assert rows["gam_deepsort_paper"]["metrics"]["mota"] == 0.64  # the shipped re-ID's row is kept
    assert rows["gam_deepsort_paper+own_reid"]["metrics"]["mota"] == 0.61
    assert "own_reid" not in "\n".join(study._ordering_section([p]))
    table = study._own_reid_section([p])
    assert "| 5 | 64.0 -> 61.0 | 93.0 -> 61.0 |" in table
    assert "| mean (folds) | 64.0 -> 61.0 (1) | 93.0 -> 61.0 (1) |" in table


def test_the_gate_study_sets_one_paper_setting_back_at_a_time_into_one_file_per_fold(tmp_path, monkeypatch):
    calls = []

    class Study:
        @staticmethod
        def track_row(row, fold, truth, weights, out, experiment, extra, folder, data=None):
            calls.append((row, fold, extra, folder))
            return metrics(0.6 + 0.01 * len(extra))

    driver = study_driver(tmp_path, monkeypatch, Study, fold=4)
    detectors = tmp_path / "det"
    (tmp_path / "wider").mkdir()
    argv = ["track.py", "--study", "wider", "--folds", "4", "--detectors", str(detectors), "--gates"]
    monkeypatch.setattr("sys.argv", argv)
    driver.main()
    assert {c[0] for c in calls} == {"yolo_deepsort_paper"} and {c[1] for c in calls} == {4}
    # the paper's settings first, then each key alone, then the two detection gates together
    assert [c[2] for c in calls][:3] == [(), ("tracker.min_confidence=0.3",), ("tracker.n_init=3",)]
    assert calls[-1][2] == ("tracker.min_confidence=0.3", "tracker.n_init=3")
    # each run its own folder, named without the characters an override value cannot hold
    folders = [c[3] for c in calls]
    assert len(set(folders)) == len(folders) and not any("=" in f or "," in f for f in folders)
    # the conf's paper settings differ from the original's exactly where the study sets them back
    paper = (REPO_ROOT / "conf/tracker/deepsort_paper.yaml").read_text()
    for extra in driver.GATES.values():
        for override in extra:
            key = override.split(".", 1)[1].split("=")[0]
            assert f"\n{key}:" in paper
    piece = json.loads((tmp_path / "wider" / "tracking" / "gates_fold4.json").read_text())
    assert piece["fold"] == 4 and list(piece["gates"]) == list(driver.GATES)
    assert piece["gates"]["min_confidence=0.3,n_init=3"]["metrics"]["mota"] == pytest.approx(0.62)
    assert not (tmp_path / "wider" / "tracking" / "yolo_deepsort_paper_fold4.json").exists()


def test_a_labelled_setting_or_another_labelling_is_tracked_into_files_of_its_own(tmp_path, monkeypatch):
    calls = []

    class Study:
        @staticmethod
        def track_row(row, fold, truth, weights, out, experiment, extra, folder, data=None):
            calls.append((row, extra, folder, data))
            return metrics(0.65)

    driver = study_driver(tmp_path, monkeypatch, Study, fold=3)
    (tmp_path / "wider").mkdir()
    argv = ["track.py", "--study", "wider", "--folds", "3", "--detectors", str(tmp_path / "det")]
    for bad in (["--set", "objectness"], ["--set", "Obj ness", "detector.score=objectness"],
                ["--set", "objectness", "detector.score"]):  # fmt: skip
        monkeypatch.setattr("sys.argv", argv + bad)
        with pytest.raises(SystemExit, match="--set .*: give a label"):
            driver.main()
    monkeypatch.setattr("sys.argv", argv + ["--gates", "--set", "objectness", "detector.score=objectness"])
    with pytest.raises(SystemExit, match="no --set or --data"):
        driver.main()
    assert calls == []
    monkeypatch.setattr("sys.argv", argv + ["--rows", "yolo_deepsort_paper", "--set", "objectness",
                                            "detector.score=objectness"])  # fmt: skip
    driver.main()
    assert calls == [
        ("yolo_deepsort_paper", ("detector.score=objectness",), "yolo_deepsort_paper_objectness", None)
    ]
    tracking = tmp_path / "wider" / "tracking"
    piece = json.loads((tracking / "yolo_deepsort_paper_objectness_fold3.json").read_text())
    assert piece["row"] == "yolo_deepsort_paper" and piece["extra"] == ["detector.score=objectness"]
    assert not (tracking / "yolo_deepsort_paper_fold3.json").exists()  # Table 4's own row untouched
    # the same sequences labelled another way: into <study>/on_<data>/tracking
    monkeypatch.setattr("sys.argv", argv + ["--gates", "--data", "relabelled"])
    with pytest.raises(SystemExit, match="no --set or --data"):
        driver.main()
    monkeypatch.setattr("sys.argv", argv + ["--rows", "yolo_deepsort_paper", "--data", "relabelled"])
    driver.main()
    assert calls[-1] == ("yolo_deepsort_paper", (), "yolo_deepsort_paper", "relabelled")
    piece = tmp_path / "wider" / "on_relabelled" / "tracking" / "yolo_deepsort_paper_fold3.json"
    assert json.loads(piece.read_text())["metrics"]["mota"] == 0.65
    assert not (tracking / "yolo_deepsort_paper_fold3.json").exists()


def tracking_piece(folder: Path, name: str, row: str, fold: int, mota: float, extra=None) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    m = {"mota": mota, "hota": mota - 0.1, "idf1": mota + 0.05, "idsw": 1.0, "fp": 2.0, "fn": 3.0}
    piece = {"row": row, "fold": fold, "metrics": m, **({"extra": extra} if extra else {})}
    (folder / f"{name}_fold{fold}.json").write_text(json.dumps(piece))


def test_the_study_table_sets_each_tracked_name_beside_ground_truth_boxes_on_its_own_folds(
    tmp_path, monkeypatch
):
    driver = study_driver(tmp_path, monkeypatch, study, fold=2)
    own = tmp_path / "wider" / "on_relabelled" / "tracking"
    ref = tmp_path / "earlier" / "on_relabelled" / "tracking"
    for fold, mota in ((2, 0.8), (4, 0.9), (5, 0.7)):
        tracking_piece(ref, "gt_deepsort_paper", "gt_deepsort_paper", fold, mota + 0.05)
    tracking_piece(own, "yolo_deepsort_paper", "yolo_deepsort_paper", 2, 0.5)
    for fold, mota in ((2, 0.6), (4, 0.8), (7, 0.8)):
        low = ["tracker.low_confidence=0.1"]
        tracking_piece(own, "yolo_deepsort_paper_low", "yolo_deepsort_paper", fold, mota, low)
    (own / "gates_fold2.json").write_text(json.dumps({"gates": {}}))  # not a row: left out
    argv = ["track.py", "--study", "wider", "--data", "relabelled", "--table"]
    monkeypatch.setattr("sys.argv", argv + ["--reference", "nowhere"])
    with pytest.raises(SystemExit, match="--reference nowhere: .* is not a study folder"):
        driver.main()
    monkeypatch.setattr("sys.argv", argv + ["--reference", "earlier"])
    driver.main()
    table = (tmp_path / "wider" / "on_relabelled" / "tracking.md").read_text()
    lines = [line for line in table.splitlines() if line.startswith("|")]
    assert (
        lines[0] == "| tracked as | 2 | 4 | 5 | 7 | folds | mean | below gt | HOTA | IDF1 | IDSW / FP / FN |"
    )
    assert lines[1].count("|---") == lines[0].count("|") - 1 == 11
    # ground truth first (from the reference study), then the names in order; the gap is taken on a
    # name's own folds and left empty where the ground truth lacks one of them (fold 7)
    assert (
        lines[2] == "| `gt_deepsort_paper` | 85.0 | 95.0 | 75.0 | - | 3 | 85.0 |  | 75.0 | 90.0 | 3 / 6 / 9 |"
    )
    assert (
        lines[3] == "| `yolo_deepsort_paper` | 50.0 | - | - | - | 1 | 50.0 | 35.0 | 40.0 | 55.0 | 1 / 2 / 3 |"
    )
    assert lines[4].startswith("| `yolo_deepsort_paper_low` | 60.0 | 80.0 | - | 80.0 | 3 | 73.3 |  |")
    assert "- `low`: `tracker.low_confidence=0.1`" in table
    assert "gates" not in table
    # nothing tracked, or a piece that is not one: a clear error, no table
    monkeypatch.setattr("sys.argv", ["track.py", "--study", "earlier", "--table"])
    with pytest.raises(SystemExit, match="no tracking pieces to tabulate"):
        driver.main()
    (ref / "gt_deepsort_paper_fold9.json").write_text("{}")
    monkeypatch.setattr("sys.argv", ["track.py", "--study", "earlier", "--data", "relabelled", "--table"])
    with pytest.raises(SystemExit, match="gt_deepsort_paper_fold9.json: not a tracking piece"):
        driver.main()
    assert not (tmp_path / "earlier" / "on_relabelled" / "tracking.md").exists()
    monkeypatch.setattr("sys.argv", ["track.py", "--study", "wider"])
    with pytest.raises(SystemExit, match="--folds: give the folds"):
        driver.main()
