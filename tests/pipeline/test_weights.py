import mlflow
import pytest

from spacetrack.pipeline.weights import MissingWeightsError, fold_artifact


def _log_run(uri: str, tags: dict, dataset: str, artifact_dir, *, status: str = "FINISHED") -> str:
    mlflow.set_tracking_uri(uri)
    experiment = mlflow.set_experiment("detector").experiment_id
    with mlflow.start_run(experiment_id=experiment, tags=tags) as run:
        mlflow.log_param("data.name", dataset)
        path = artifact_dir / "best.pt"
        path.write_text(run.info.run_id)
        mlflow.log_artifact(str(path), "weights")
    if status != "FINISHED":
        mlflow.MlflowClient().set_terminated(run.info.run_id, status)
    return run.info.run_id


def _plain_fold3(uri: str, **tags):
    return fold_artifact(
        experiment="detector",
        fold=3,
        dataset="space_default",
        artifact="weights/best.pt",
        train=("spacetrack.train", ["fold=3"]),
        tags={"gam_position": "none", **tags},
        tag_defaults={"head_levels": "3"},
        tracking_uri=uri,
    )


def test_the_newest_finished_run_of_the_fold_with_the_tags_wins(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    uri = f"sqlite:///{tmp_path}/m.db"
    plain = {"fold": "3", "gam_position": "none"}
    (tmp_path / "a").mkdir()
    older = _log_run(uri, plain, "space_default", tmp_path / "a")
    _log_run(uri, {"fold": "3", "gam_position": "after_sppf"}, "space_default", tmp_path / "a")
    _log_run(uri, {"fold": "4", "gam_position": "none"}, "space_default", tmp_path / "a")
    _log_run(uri, plain, "space_smoke", tmp_path / "a")
    _log_run(uri, plain, "space_default", tmp_path / "a", status="FAILED")
    mlflow.end_run()
    assert _plain_fold3(uri).read_text() == older
    newer = _log_run(uri, plain, "space_default", tmp_path / "a")
    assert _plain_fold3(uri).read_text() == newer
    with pytest.raises(MissingWeightsError, match="no trained weights for fold 5"):
        fold_artifact(
            experiment="detector",
            fold=5,
            dataset="space_default",
            artifact="weights/best.pt",
            train=("spacetrack.train", ["fold=5"]),
            tracking_uri=uri,
        )


def test_a_tag_with_a_default_matches_runs_made_before_it_existed(tmp_path, monkeypatch):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    uri = f"sqlite:///{tmp_path}/m.db"
    (tmp_path / "a").mkdir()
    old = _log_run(uri, {"fold": "3", "gam_position": "none"}, "space_default", tmp_path / "a")
    p2 = _log_run(
        uri, {"fold": "3", "gam_position": "none", "head_levels": "4"}, "space_default", tmp_path / "a"
    )
    mlflow.end_run()

    def lookup(levels: str) -> str:
        return _plain_fold3(uri, head_levels=levels).read_text()

    assert lookup("3") == old  # the newer four-level run is not a three-level one
    assert lookup("4") == p2
    three = _log_run(
        uri, {"fold": "3", "gam_position": "none", "head_levels": "3"}, "space_default", tmp_path / "a"
    )
    assert lookup("3") == three
