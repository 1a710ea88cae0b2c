"""The Table 4 runner trains a piece's missing models when asked to, and only then."""

from __future__ import annotations

import importlib.util
import json
import subprocess

import pytest

from spacetrack.config import REPO_ROOT
from spacetrack.pipeline.weights import MissingWeightsError

spec = importlib.util.spec_from_file_location("table4_run", REPO_ROOT / "experiments/table4_mota/run.py")
table4 = importlib.util.module_from_spec(spec)
spec.loader.exec_module(table4)


@pytest.fixture
def fake_world(monkeypatch):
    """run_piece finds a detector only once one was trained, then a re-ID network the same way."""
    trained, commands = set(), []

    def run_piece(row, fold, common):
        for module, overrides in (("spacetrack.train", [f"fold={fold}", "model=yolov5s_gam"]),
                                  ("spacetrack.train_reid", [f"fold={fold}"])):  # fmt: skip
            if module not in trained:
                raise MissingWeightsError(f"no {module} for fold {fold}", train=(module, overrides))
        return {"row": row, "fold": fold, "metrics": {"mota": 0.5}}

    def run(command, cwd, check):
        commands.append(command[1:])
        trained.add(command[2])
        return subprocess.CompletedProcess(command, 0)

    monkeypatch.setattr(table4, "run_piece", run_piece)
    monkeypatch.setattr(table4.subprocess, "run", run)
    return commands


def test_missing_models_are_trained_with_the_extra_arguments_then_the_piece_runs(fake_world):
    # resume=...: a training stopped part-way by an earlier, killed runner goes on from its last epoch.
    extra = {"spacetrack.train": ["train.threads=1"], "spacetrack.train_reid": ["train_reid.threads=1"]}
    record = table4.run_with_models("gam_deepsort_paper", 2, [], extra)
    assert record["metrics"]["mota"] == 0.5
    assert fake_world == [
        ["-m", "spacetrack.train", "fold=2", "model=yolov5s_gam", "resume=auto", "train.threads=1"],
        ["-m", "spacetrack.train_reid", "fold=2", "resume=auto", "train_reid.threads=1"],
    ]


def test_without_train_a_missing_model_is_an_error_and_nothing_trains(fake_world):
    with pytest.raises(MissingWeightsError, match="no spacetrack.train for fold 2"):
        table4.run_with_models("gam_deepsort_paper", 2, [], None)
    assert fake_world == []


def test_a_model_still_missing_after_its_training_stops_the_runner(monkeypatch, fake_world):
    def never_found(row, fold, common):
        raise MissingWeightsError("still none", train=("spacetrack.train", [f"fold={fold}"]))

    monkeypatch.setattr(table4, "run_piece", never_found)
    with pytest.raises(RuntimeError, match="still not found"):
        table4.run_with_models("yolo_sort", 1, [], {})
    assert len(fake_world) == 1


def test_settings_hash_ignores_fold_output_and_speed_but_not_what_changes_numbers():
    base = table4.settings_hash(table4.piece_overrides("gt_sort", 0, []))
    same = table4.piece_overrides("gt_sort", 5, ["threads=1", "motion.parallel=true", "reid.threads=2"])
    assert table4.settings_hash(same) == base
    for change in (
        "tracker.max_age=5",
        "motion.hull_margin=null",
        "dynamic.min_overlap=0.5",
        "iou_threshold=0.3",
    ):
        assert table4.settings_hash(table4.piece_overrides("gt_sort", 0, [change])) != base, change
    assert table4.settings_hash(table4.piece_overrides("gt_deepsort_paper", 0, [])) != base


def test_the_detection_score_counts_only_when_it_is_not_the_class_score_of_before():
    paper = table4.piece_overrides("yolo_deepsort_paper", 0, [])
    assert table4.settings_hash(paper) == table4.settings_hash(paper + ["detector.score=class"])
    objectness = table4.piece_overrides("yolo_deepsort_paper_objectness", 0, [])
    assert "detector.score=objectness" in objectness
    assert table4.settings_hash(objectness) != table4.settings_hash(paper)


def test_re_id_weights_count_only_for_a_tracker_that_matches_on_appearance():
    sort = table4.piece_overrides("yolo_sort", 0, [])
    with_features = table4.piece_overrides("yolo_sort", 0, ["reid.weights=weights/reid_fold3.pt"])
    assert table4.settings_hash(with_features) == table4.settings_hash(sort)  # SORT never reads them
    deepsort = table4.piece_overrides("yolo_deepsort_original", 0, [])
    assert table4.settings_hash(deepsort + ["reid.weights=weights/reid_fold3.pt"]) != table4.settings_hash(
        deepsort
    )


def test_the_dynamic_hold_counts_only_where_it_acts():
    # The paper's rows run without the hold (frames=0): their hash is that of before the option existed,
    # and with the filter off the hold has nothing to act on.
    paper = table4.piece_overrides("gt_sort", 0, [])
    assert "dynamic_hold.frames=0" in paper
    hold = table4.piece_overrides("gt_sort_hold", 0, [])
    assert table4.settings_hash(hold) != table4.settings_hash(paper)
    assert table4.settings_hash(hold) != table4.settings_hash(hold + ["dynamic_hold.frames=10"])
    nofilter = table4.piece_overrides("gt_sort_nofilter", 0, [])
    assert table4.settings_hash(nofilter) == table4.settings_hash(nofilter + ["dynamic_hold.frames=5"])
    assert table4.settings_hash(paper) == table4.settings_hash(paper + ["dynamic_hold.min_iou=0.9"])


def test_offline_rows_hash_apart_and_offline_keys_count_only_when_enabled():
    online = table4.piece_overrides("gt_deepsort_original", 0, [])
    offline = table4.piece_overrides("gt_deepsort_original_offline", 0, [])
    assert "OFFLINE" in table4.ROWS["gt_deepsort_original_offline"][0]
    assert table4.settings_hash(offline) != table4.settings_hash(online)
    assert table4.settings_hash(offline) != table4.settings_hash(offline + ["offline.max_gap=5"])
    # off, the offline keys do not act: the online pieces keep the hash they had before the option existed
    assert table4.settings_hash(online) == table4.settings_hash(online + ["offline.max_gap=5"])


@pytest.fixture
def results_dir(tmp_path, monkeypatch):
    """The runner's results and tables under tmp_path, pieces 'tracked' by a stub that counts its calls."""
    calls = []

    def run_piece(row, fold, common):
        calls.append((row, fold))
        overrides = table4.piece_overrides(row, fold, common)
        metrics = {m: 0.5 for m in table4.SHOWN}
        return {"row": row, "fold": fold, "metrics": metrics, "settings": table4.settings_hash(overrides),
                "command": "python -m spacetrack.track " + " ".join(overrides), "profile": "CPU"}  # fmt: skip

    monkeypatch.setattr(table4, "run_piece", run_piece)
    monkeypatch.setattr(table4, "HERE", tmp_path)
    monkeypatch.setattr(table4, "RESULTS", tmp_path / "results")
    return tmp_path, calls


def _main(monkeypatch, *argv):
    monkeypatch.setattr(table4.sys, "argv", ["run.py", *argv])
    table4.main()


def test_current_pieces_are_kept_stale_ones_recomputed_and_starred_until_then(results_dir, monkeypatch):
    root, calls = results_dir
    _main(monkeypatch, "--rows", "gt_sort", "--folds", "0-1")
    assert calls == [("gt_sort", 0), ("gt_sort", 1)]
    _main(monkeypatch, "--rows", "gt_sort", "--folds", "0-1")
    assert len(calls) == 2  # both current: nothing recomputed
    old = root / "results/gt_sort/fold1.json"
    record = json.loads(old.read_text())
    record["settings"] = "made-by-older-settings"
    old.write_text(json.dumps(record))
    table4.write_tables()
    table = (root / "table4.md").read_text()
    assert "| 50.0 | 50.0* |" in table and "1 cells were made with other settings" in table
    _main(monkeypatch, "--rows", "gt_sort", "--folds", "0-1")
    assert calls[2:] == [("gt_sort", 1)]
    assert "*" not in (root / "table4.md").read_text().split("Commands per row")[0]
    _main(monkeypatch, "--rows", "gt_sort", "--folds", "0", "--redo")
    assert calls[3:] == [("gt_sort", 0)]


def test_a_group_name_runs_each_of_its_rows(results_dir, monkeypatch):
    _, calls = results_dir
    _main(monkeypatch, "--rows", "gt_peers", "--folds", "0")
    assert calls == [(f"gt_{peer}", 0) for peer in table4.PEERS]
    assert set(table4.GROUPS["gt_peers"]) < set(table4.GROUPS["peers"])


def test_scenarios_pool_mota_exactly_and_weight_hota_by_boxes(results_dir):
    root, _ = results_dir

    def seq(scenario, boxes, errors, hota):
        return {
            "scenario": scenario,
            "gt_boxes": boxes,
            "fn": errors,
            "fp": 0,
            "idsw": 0,
            "hota": hota,
            "idf1": hota,
        }

    record = {"row": "gt_bytetrack", "metrics": {m: 0.5 for m in table4.SHOWN}, "settings": "s",
              "command": "python -m spacetrack.track fold=0", "profile": "CPU"}  # fmt: skip
    for fold, sequences in enumerate([{"a": seq("dim", 100, 10, 0.8)}, {"b": seq("dim", 300, 20, 0.6)}]):
        path = root / "results/gt_bytetrack" / f"fold{fold}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(record | {"fold": fold, "sequences": sequences}))
    older = root / "results/gt_sort/fold0.json"  # made before HOTA was scored: no hota, no sequences
    older.parent.mkdir(parents=True)
    older.write_text(json.dumps(record | {"row": "gt_sort", "fold": 0, "metrics": {"mota": 0.7, "idf1": 0.7,
                                                                                 "idsw": 0, "fp": 0, "fn": 0}}))  # fmt: skip
    table4.write_tables(current={})
    dim = json.loads((root / "table4.json").read_text())["gt_bytetrack"]["scenarios"]["dim"]
    assert dim["mota"] == pytest.approx(1 - 30 / 400)  # (10 + 20) errors over 400 boxes
    assert dim["hota"] == pytest.approx((100 * 0.8 + 300 * 0.6) / 400)
    table = (root / "table4.md").read_text()
    assert "| `gt_bytetrack` | 92.5 / 65.0 | 2 |" in table
    mota_table, hota_table = (
        table.split("## HOTA\n")[0],
        table.split("## HOTA\n")[1].split("## MOTA / HOTA")[0],
    )
    assert "`gt_sort`" in mota_table and "`gt_sort`" not in hota_table


def test_the_paper_rows_run_the_reference_matching_and_the_track_rows_reacquire():
    paper = table4.piece_overrides("gam_deepsort_paper", 0, [])
    track = table4.piece_overrides("gt_deepsort_original", 0, [])
    assert "tracker.reacquire_gate=null" in paper  # the reference matching
    assert table4.settings_hash(track) != table4.settings_hash(track + ["tracker.reacquire_gate=null"])


def test_the_paper_rows_keep_yolov5s_nms_and_drop_low_scored_boxes_while_make_track_has_them():
    from spacetrack.config import compose_config

    default = compose_config("track", [])
    assert default.detector.agnostic_nms and default.detector.part_overlap == 0.8
    assert default.tracker.low_confidence == 0.3  # the deepsort_paper preset
    for row in ("gam_deepsort_paper", "yolo_deepsort_paper", "yolo_deepsort_original"):
        cfg = compose_config("track", table4.piece_overrides(row, 0, []))
        assert not cfg.detector.agnostic_nms and cfg.detector.part_overlap is None, row
        assert cfg.tracker.low_confidence is None, row
    # ground-truth boxes all score 1.0: no low-scored box exists, so the setting does not change the hash
    gt = table4.piece_overrides("gt_deepsort_paper", 0, [])
    assert table4.settings_hash(gt) == table4.settings_hash(gt + ["tracker.low_confidence=null"])
