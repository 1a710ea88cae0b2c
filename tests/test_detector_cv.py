"""The detector study (cross-validation and ablation) reuses a finished detector run only when it was
trained exactly as asked, and tabulates its pieces."""

from __future__ import annotations

import importlib.util
import json

import pytest
from omegaconf import open_dict

from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.data.layout import FORMAT_VERSION, MANIFEST
from spacetrack.engine.pretrained import PRETRAINED
from spacetrack.mlflow_log import log_artifact_file, log_metrics_step, start_run

spec = importlib.util.spec_from_file_location("detector_cv", REPO_ROOT / "experiments/detector_cv/run.py")
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


def write_manifest(data_root, content: str) -> None:
    """A dataset manifest under `data_root` (the study reads only its content hash)."""
    folder = data_root / "space_default"
    folder.mkdir(parents=True, exist_ok=True)
    manifest = {"format_version": FORMAT_VERSION, "name": "space_default", "content_hash": content}
    (folder / MANIFEST).write_text(json.dumps(manifest))


@pytest.fixture
def train_config(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    write_manifest(tmp_path / "data", "sha256:0")

    def make(*overrides):
        cfg = compose_config(
            "train",
            ["fold=3", f"output_dir={tmp_path}", f"logger.tracking_uri={uri}", f"data_root={tmp_path / 'data'}",
             *overrides],
        )  # fmt: skip
        with open_dict(cfg):
            cfg.cv_parent_run_id = None
        return cfg

    return make


def finished_run(cfg, weights, map50: float, content: str | None = "sha256:0") -> str:
    tags = {"fold": str(cfg.fold)} | ({} if content is None else {"data_content": content})
    with start_run(cfg, tags=tags) as run:
        log_metrics_step({"best_map50": map50, "best_map50_95": map50 / 2}, step=0)
        log_artifact_file(weights, "weights")
        return run.info.run_id


def test_a_run_is_reused_only_with_the_same_enhancement_and_training(train_config, tmp_path):
    weights = tmp_path / "best.pt"
    weights.write_bytes(b"weights")
    plain = finished_run(train_config("enhance=none"), weights, 0.4)
    enhanced = finished_run(train_config("enhance=dwt_hsv"), weights, 0.5)
    found = study.matching_run(train_config("enhance=dwt_hsv"))
    assert found is not None
    run_id, best, local = found
    assert run_id == enhanced and best["map50"] == 0.5 and local.read_bytes() == b"weights"
    # threads only change the speed: still the same run; other epochs or another model: none
    assert study.matching_run(train_config("enhance=none", "train.threads=1"))[0] == plain
    assert study.matching_run(train_config("enhance=none", "train.trainer.epochs=3")) is None
    assert study.matching_run(train_config("enhance=none", "model=yolov5s_gam")) is None
    assert study.matching_run(train_config("enhance=none", "weights=none")) is None  # another start


def test_a_run_made_before_a_training_key_existed_matches_that_keys_earlier_value(train_config, tmp_path):
    weights = tmp_path / "best.pt"
    weights.write_bytes(b"weights")
    cfg = train_config("enhance=none")
    older = train_config("enhance=none")
    with open_dict(older):
        del older.train.trainer["sync_bn"]  # as the runs made before the key was added logged it
    run_id = finished_run(older, weights, 0.4)
    assert study.matching_run(cfg)[0] == run_id
    assert study.matching_run(train_config("enhance=none", "train.trainer.sync_bn=true")) is None
    older = train_config("enhance=none")
    with open_dict(older):
        del older.train.augment["exposure"], older.train.augment["exposure_gain"]
    run_id = finished_run(older, weights, 0.5)
    assert study.matching_run(cfg)[0] == run_id  # re-exposure off, as before it existed
    assert study.matching_run(train_config("enhance=none", "train.augment.exposure=0.5")) is None


def test_a_run_is_reused_only_on_the_same_dataset_content(train_config, tmp_path):
    weights = tmp_path / "best.pt"
    weights.write_bytes(b"weights")
    cfg = train_config("enhance=none")
    other = finished_run(cfg, weights, 0.4, content="sha256:1")  # the dataset was re-rendered since
    assert study.matching_run(cfg) is None
    untagged = finished_run(cfg, weights, 0.5, content=None)  # made before the tag existed: cannot tell
    assert study.matching_run(cfg)[0] == untagged != other
    write_manifest(tmp_path / "data", "sha256:1")
    assert study.matching_run(cfg)[0] == untagged  # the newest of the two that may match
    same = finished_run(cfg, weights, 0.6, content="sha256:1")
    assert study.matching_run(cfg)[0] == same


def test_table_lists_each_fold_and_the_means_per_scenario():
    def piece(slug, fold, map50, dim):
        overall = {"map50": map50, "map50_95": map50 / 2, "recall_at_score": 0.9, "frames": 300}
        return {"slug": slug, "fold": fold, "overrides": [], "all": overall,
                "dim": {"map50": dim, "map50_95": dim / 2, "recall_at_score": 0.8, "frames": 75}}  # fmt: skip

    scored_any_class = piece("dwt_hsv_gam", 3, 0.95, 0.9)
    scored_any_class["all"] |= {"map50_any": 0.97, "recall_at_score_any": 0.96}
    scored_multi = piece("yolov5s", 4, 0.8, 0.5)
    scored_multi["all"] |= {"map50_any": 0.9, "recall_at_score_any": 0.85, "map50_multi": 0.82,
                            "map50_95_multi": 0.41}  # fmt: skip
    scored_multi["confusion"] = {"classes": ["a", "b"], "counts": [[5, 1, 2], [3, 4, 0], [1, 0, 0]]}
    also = piece("yolov5s", 5, 0.8, 0.5) | {"confusion": {"classes": ["a", "b"], "counts": [[1] * 3] * 3}}
    text = study.table([piece("yolov5s", 3, 0.9, 0.7), scored_multi, scored_any_class, also])
    assert "test-time augmentation" not in text
    views = [[1.0, False], [0.83, True]]
    augmented = study.table([piece("yolov5s", 3, 0.9, 0.7) | {"tta": views}])
    assert "detected with test-time augmentation (scale, mirrored: 1.0 as is, 0.83 mirrored)" in augmented
    # scored before the any-class and multi-label metrics
    assert "| YOLOv5s | 3 | 0.900 | 0.450 | 0.900 | - | - | 300 |" in text
    assert "| +DWT/HSV +GAM | 3 | 0.950 | 0.475 | 0.900 | 0.970 / 0.960 | - | 300 |" in text
    assert "| YOLOv5s | 4 | 0.800 | 0.400 | 0.900 | 0.900 / 0.850 | 0.820 / 0.410 | 300 |" in text
    assert "| YOLOv5s | 3,4,5 | 0.833 | 0.417 | 0.900 | 0.567 / 0.800 |" in text
    # the confusion matrices of the pieces that have one, summed
    assert "YOLOv5s, folds 4,5: true class (rows)" in text
    assert "| true / predicted | a | b | missed |" in text
    assert "| a | 6 | 2 | 3 |\n| b | 4 | 5 | 1 |\n| background | 2 | 1 | 1 |" in text
    assert "| +DWT/HSV +GAM | 3 | 0.950 | 0.475 | 0.900 | 0.900 / 0.800 |" in text


def test_rescoring_takes_the_pieces_own_run_or_leaves_the_piece_alone(train_config, tmp_path, monkeypatch):
    weights = tmp_path / "best.pt"
    weights.write_bytes(b"weights")
    overrides = [f"output_dir={tmp_path}", f"logger.tracking_uri=sqlite:///{tmp_path / 'mlflow.db'}",
                 f"data_root={tmp_path / 'data'}"]  # fmt: skip
    cfg = study.variant_config("yolov5s", 3, overrides, tmp_path)
    run_id = finished_run(cfg, weights, 0.4)
    scored = []

    def score(cfg, w, stride, augment=False):
        scored.append((w.read_bytes(), augment))
        return {"all": {"x": 2 if augment else 1}}

    monkeypatch.setattr(study, "score", score)
    old = {"slug": "yolov5s", "fold": 3, "overrides": overrides, "run_id": run_id, "all": {"x": 0}, "dim": {}}
    assert study.rescored(old, 2, tmp_path) == {**old, "all": {"x": 1}} and scored == [(b"weights", False)]
    elsewhere = {**old, "run_id": "f" * 32}  # trained on another machine: its run is not in this store
    assert study.rescored(elsewhere, 2, tmp_path) is None and len(scored) == 1
    # --tta: the same weights with test-time augmentation, the views recorded in the piece
    augmented = study.rescored(old, 2, tmp_path, augment=True)
    assert augmented["all"] == {"x": 2} and scored[-1] == (b"weights", True)
    assert augmented["tta"] == [[1.0, False], [0.83, True], [0.67, False]]


def test_start_only_scores_the_weights_a_training_would_start_from(train_config, tmp_path, monkeypatch):
    start = tmp_path / "start.pt"
    start.write_bytes(b"pretrained")
    overrides = [f"output_dir={tmp_path}", f"logger.tracking_uri=sqlite:///{tmp_path / 'mlflow.db'}",
                 f"data_root={tmp_path / 'data'}", f"weights={start}"]  # fmt: skip
    scored = []
    monkeypatch.setattr(
        study,
        "score",
        lambda cfg, w, stride, augment=False: scored.append(w.read_bytes()) or {"all": {"x": 1}},
    )
    monkeypatch.setattr(study, "fit", lambda cfg: pytest.fail("--start-only trained"))
    (tmp_path / "configs").mkdir()  # main() makes it
    got = study.piece("yolov5s", 3, overrides, 2, tmp_path, start_only=True)
    assert scored == [b"pretrained"] and got["start_only"] and got["run_id"] is None
    assert got["start"] == str(start) and got["start_hash"].startswith("sha256:")
    assert (tmp_path / "configs" / "yolov5s_fold3.yaml").is_file()
    # rescored from the same file; a start that has changed since leaves the piece alone
    result = {"slug": "yolov5s", "fold": 3, "overrides": overrides, **got}
    assert study.rescored(result, 2, tmp_path) == result and len(scored) == 2
    start.write_bytes(b"pretrained again")
    assert study.rescored(result, 2, tmp_path) is None and len(scored) == 2
    # auto: the shipped file of the model's GAM position; none: nothing to score
    cfg = study.variant_config("dwt_hsv_gam", 3, overrides[:3], tmp_path)
    assert study.start_weights(cfg) == PRETRAINED["after_sppf"]
    with pytest.raises(SystemExit, match="weights=none names no weights file"):
        study.start_weights(study.variant_config("yolov5s", 3, [*overrides[:3], "weights=none"], tmp_path))
    piece = {"slug": "yolov5s", "fold": 3, "overrides": [], "start_only": True,
             "all": {"map50": 0.9, "map50_95": 0.5, "recall_at_score": 0.8, "frames": 10}}  # fmt: skip
    assert "the start's weights, not fine-tuned" in study.table([piece])
    assert "each fold's best epoch" in study.table([{**piece, "start_only": False}])


def test_scoring_on_another_labelling_refuses_other_sequences_or_folds(tmp_path):
    spec = importlib.util.spec_from_file_location(
        "score_on", REPO_ROOT / "experiments/detector_cv/score_on.py"
    )
    score_on = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(score_on)
    sequences = [
        {"name": f"seq_{i:03d}_dim", "scenario": "dim", "seed": [0, i], "fold": i % 3} for i in range(6)
    ]
    for name, moved in (("a", {}), ("b", {}), ("c", {"fold": 2})):
        (tmp_path / name).mkdir()
        rows = [s | (moved if s["name"] == "seq_001_dim" else {}) for s in sequences]
        manifest = {"format_version": FORMAT_VERSION, "sequences": rows}
        (tmp_path / name / MANIFEST).write_text(json.dumps(manifest))
    score_on.check_same_sequences(tmp_path / "a", tmp_path / "b")
    with pytest.raises(SystemExit, match=r"sequences or folds differ .*1 differ.*seq_001_dim"):
        score_on.check_same_sequences(tmp_path / "a", tmp_path / "c")
    assert score_on.trained_dataset({"overrides": ["data.name=x", "data.name=y"]}) == "y"
    assert score_on.trained_dataset({"overrides": []}) == "space_default"
