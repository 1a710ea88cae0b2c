"""spacetrack.mlflow_log against a throwaway sqlite store, and against a real `mlflow server` over REST."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import urllib.parse
import urllib.request
from pathlib import Path

import mlflow
import numpy as np
import pytest
from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH
from omegaconf import DictConfig

from spacetrack import mlflow_log
from spacetrack.config import CONF_DIR, REPO_ROOT, compose_config

LONG_VALUE = "x" * (MAX_PARAM_VAL_LENGTH + 100)


@pytest.fixture(autouse=True)
def _isolated_tracking_uri(monkeypatch: pytest.MonkeyPatch):
    # mlflow.set_tracking_uri also exports MLFLOW_TRACKING_URI; keep that from leaking into other tests.
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    yield
    mlflow.set_tracking_uri(None)


@pytest.fixture(scope="module")
def config_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A root config that pulls the project's real logger group from conf/."""
    folder = tmp_path_factory.mktemp("conf")
    (folder / "probe.yaml").write_text(
        "defaults:\n  - logger: mlflow\n  - _self_\n"
        f"hydra:\n  searchpath:\n    - file://{CONF_DIR}\n"
        "task_name: probe\n"
        "model:\n  lr: 0.01\n  layers: [1, 2]\n  name: ${task_name}-net\n"
        f"note: {LONG_VALUE}\n"
    )
    return folder


@pytest.fixture(scope="module")
def store(tmp_path_factory: pytest.TempPathFactory) -> str:
    # One database for the module: creating a fresh MLflow schema costs seconds on this machine.
    return f"sqlite:///{tmp_path_factory.mktemp('store') / 'mlflow.db'}"


def make_cfg(config_dir: Path, *overrides: str) -> DictConfig:
    return compose_config("probe", list(overrides), config_dir=config_dir)


def runs_of(experiment: str) -> list[mlflow.entities.Run]:
    client = mlflow.MlflowClient()
    return client.search_runs([client.get_experiment_by_name(experiment).experiment_id])


def test_tracking_uri_defaults_and_anchoring(monkeypatch: pytest.MonkeyPatch) -> None:
    assert mlflow_log.tracking_uri() == f"sqlite:///{REPO_ROOT / 'mlflow.db'}"
    assert mlflow_log.tracking_uri("sqlite:///mlflow.db") == f"sqlite:///{REPO_ROOT / 'mlflow.db'}"
    assert mlflow_log.tracking_uri("sqlite:////abs/x.db") == "sqlite:////abs/x.db"
    monkeypatch.setenv("MLFLOW_TRACKING_URI", "http://tracking.example:5000")
    assert mlflow_log.tracking_uri() == "http://tracking.example:5000"
    assert mlflow_log.tracking_uri("http://other:1") == "http://other:1"


def test_run_logs_config_commit_artifact_and_metrics(config_dir: Path, store: str, tmp_path: Path) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=logs")
    plot = tmp_path / "curve.txt"
    plot.write_text("0.1 0.2\n")
    with mlflow_log.start_run(cfg, run_name="probe-run", tags={"stage": "unit"}) as run:
        assert run is not None
        for step, loss in enumerate([1.0, 0.5, 0.25]):
            mlflow_log.log_metrics_step({"loss": loss}, step)
        mlflow_log.log_artifact_file(plot, artifact_path="plots")

    client = mlflow.MlflowClient()
    logged = client.get_run(run.info.run_id)
    assert logged.info.status == "FINISHED"
    assert logged.info.run_name == "probe-run"
    params = logged.data.params
    assert params["model.lr"] == "0.01"
    assert params["model.layers"] == "[1, 2]"
    assert params["model.name"] == "probe-net"
    assert params["logger.experiment"] == "logs"
    assert params["note"] == LONG_VALUE[:MAX_PARAM_VAL_LENGTH]
    head = subprocess.run(
        ["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    ).stdout.strip()
    assert logged.data.tags[mlflow_log.GIT_COMMIT_TAG] == head
    assert logged.data.tags["git_dirty"] in {"true", "false"}
    assert logged.data.tags["stage"] == "unit"
    assert [m.value for m in client.get_metric_history(run.info.run_id, "loss")] == [1.0, 0.5, 0.25]
    artifacts = {a.path for a in client.list_artifacts(run.info.run_id)}
    assert artifacts == {"config.yaml", "plots"}
    assert [a.path for a in client.list_artifacts(run.info.run_id, "plots")] == ["plots/curve.txt"]
    config_text = Path(client.download_artifacts(run.info.run_id, "config.yaml", str(tmp_path))).read_text()
    assert "lr: 0.01" in config_text
    experiment = client.get_experiment(logged.info.experiment_id)
    assert experiment.tags.items() >= mlflow_log.EXPERIMENT_TAGS.items()
    # Artifacts of a sqlite store live beside its database, not in the working directory.
    store_dir = Path(store.removeprefix("sqlite:///")).parent
    assert logged.info.artifact_uri.startswith((store_dir / "mlartifacts").as_uri())


def test_disabled_logger_logs_nothing(
    config_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MLFLOW_TRACKING_URI", f"sqlite:///{tmp_path / 'should_not_exist.db'}")
    artifact = tmp_path / "a.txt"
    artifact.write_text("a")
    cfg = make_cfg(config_dir, "logger=none")
    with mlflow_log.start_run(cfg) as run:
        assert run is None
        assert mlflow.active_run() is None
        mlflow_log.log_metrics_step({"loss": 1.0}, 0)
        mlflow_log.log_artifact_file(artifact)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]


def test_failing_block_marks_run_failed_and_ctrl_c_killed(config_dir: Path, store: str) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=failures")
    with pytest.raises(RuntimeError, match="boom"), mlflow_log.start_run(cfg, run_name="fails"):
        raise RuntimeError("boom")
    with pytest.raises(KeyboardInterrupt), mlflow_log.start_run(cfg, run_name="interrupted"):
        raise KeyboardInterrupt
    assert mlflow.active_run() is None
    assert {r.info.run_name: r.info.status for r in runs_of("failures")} == {
        "fails": "FAILED",
        "interrupted": "KILLED",
    }


def test_sigterm_inside_a_run_marks_it_killed_and_restores_the_handler(config_dir: Path, store: str) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=terminated")
    before = signal.getsignal(signal.SIGTERM)
    with pytest.raises(mlflow_log.Terminated), mlflow_log.start_run(cfg, run_name="stopped"):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises long before this ends
    assert signal.getsignal(signal.SIGTERM) is before
    # The same signal can reach a data-loader worker first, and the error the run ends with is then
    # the loader's: still a stopped run, not a failed one.
    with pytest.raises(RuntimeError, match="worker"), mlflow_log.start_run(cfg, run_name="loader"):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except mlflow_log.Terminated:
            raise RuntimeError("DataLoader worker is killed by signal: Terminated") from None
    assert mlflow.active_run() is None
    statuses = {r.info.run_name: r.info.status for r in runs_of("terminated")}
    assert statuses == {"stopped": "KILLED", "loader": "KILLED"}


def test_continuing_a_run_reopens_it_without_touching_its_params(
    config_dir: Path, store: str, tmp_path: Path
) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=continued")
    with pytest.raises(KeyboardInterrupt), mlflow_log.start_run(cfg, run_name="long") as first:
        mlflow_log.log_metrics_step({"loss": 1.0}, 0)
        raise KeyboardInterrupt
    changed = make_cfg(
        config_dir, f"logger.tracking_uri={store}", "logger.experiment=continued", "model.lr=0.5"
    )
    mlflow.set_experiment("another")  # the process's active experiment is not the run's
    with mlflow_log.start_run(changed, run_name="ignored", continue_run_id=first.info.run_id) as second:
        mlflow_log.log_metrics_step({"loss": 0.5}, 1)
    assert second.info.run_id == first.info.run_id
    client = mlflow.MlflowClient()
    run = client.get_run(first.info.run_id)
    assert (run.info.status, run.info.run_name) == ("FINISHED", "long")
    assert run.data.params["model.lr"] == "0.01"  # as first logged; the resume's config is an artifact
    assert run.data.tags["resumes"] == "1"
    assert {a.path for a in client.list_artifacts(run.info.run_id)} == {"config.yaml", "config_resume1.yaml"}
    resumed = Path(
        client.download_artifacts(run.info.run_id, "config_resume1.yaml", str(tmp_path))
    ).read_text()
    assert "lr: 0.5" in resumed
    assert [m.value for m in client.get_metric_history(run.info.run_id, "loss")] == [1.0, 0.5]
    # An id this store does not have (a checkpoint made elsewhere) starts a new run.
    with mlflow_log.start_run(cfg, run_name="fresh", continue_run_id="0" * 32) as third:
        pass
    assert third.info.run_id != first.info.run_id
    assert client.get_run(third.info.run_id).data.params["model.lr"] == "0.01"


def test_missing_artifact_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="nope.png"):
        mlflow_log.log_artifact_file(tmp_path / "nope.png")


def test_cross_validation_parent_gets_mean_and_std(config_dir: Path, store: str) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=cv")
    mota = [0.5, 0.6, 0.8]
    with mlflow_log.start_run(cfg, run_name="cv") as parent:
        parent_id = parent.info.run_id
        for fold, value in enumerate(mota):
            with mlflow_log.start_run(cfg, run_name=f"fold{fold}", parent_run_id=parent_id):
                mlflow_log.log_metrics_step({"mota": value, "idf1": 1.0 - value}, fold)
        # A fold that crashed is left out of the summary.
        with pytest.raises(ValueError), mlflow_log.start_run(cfg, run_name="broken", nested=True):
            mlflow_log.log_metrics_step({"mota": 100.0}, 0)
            raise ValueError("fold crashed")
    summary = mlflow_log.cv_parent_summary(parent_id, ["mota", "idf1"])

    assert summary["mota_mean"] == pytest.approx(np.mean(mota))
    assert summary["mota_std"] == pytest.approx(np.std(mota))
    assert summary["idf1_mean"] == pytest.approx(1.0 - np.mean(mota))
    client = mlflow.MlflowClient()
    assert client.get_run(parent_id).data.metrics == pytest.approx(summary)
    children = [r for r in runs_of("cv") if r.info.run_id != parent_id]
    assert len(children) == 4
    assert {r.data.tags[mlflow_log.PARENT_RUN_TAG] for r in children} == {parent_id}
    with pytest.raises(ValueError, match="'loss'"):
        mlflow_log.cv_parent_summary(parent_id, ["loss"])


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=10) as response:
        return json.loads(response.read())


def wait_healthy(base: str, server: subprocess.Popen, log: Path, timeout_s: float = 90.0) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if server.poll() is not None:
            pytest.fail(f"mlflow server exited with {server.returncode}:\n{log.read_text()[-3000:]}")
        try:
            with urllib.request.urlopen(f"{base}/health", timeout=2) as response:
                if response.status == 200:
                    return
        except OSError:
            time.sleep(0.5)
    pytest.fail(f"mlflow server did not answer /health within {timeout_s} s:\n{log.read_text()[-3000:]}")


@pytest.mark.slow
def test_real_server_round_trip_over_rest(config_dir: Path, tmp_path: Path) -> None:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    log = tmp_path / "server.log"
    command = [sys.executable, "-m", "mlflow", "server", "--backend-store-uri", f"sqlite:///{tmp_path}/s.db"]
    command += ["--artifacts-destination", str(tmp_path / "art"), "--host", "127.0.0.1", "--port", str(port)]
    command += ["--workers", "1"]
    with log.open("w") as out:
        # Own process group: the server forks workers, and all of them must go when the test ends.
        server = subprocess.Popen(
            command,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
            # The server's background job runner is not needed here and costs a dozen processes.
            env={**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"},
        )
    try:
        wait_healthy(base, server, log)
        cfg = make_cfg(config_dir, f"logger.tracking_uri={base}", "logger.experiment=served")
        clip = tmp_path / "clip.txt"
        clip.write_text("frames")
        with mlflow_log.start_run(cfg, run_name="served-run") as run:
            mlflow_log.log_metrics_step({"mota": 0.75}, 3)
            mlflow_log.log_artifact_file(clip, artifact_path="video")
        run_id = run.info.run_id

        fetched = get_json(f"{base}/api/2.0/mlflow/runs/get?run_id={run_id}")["run"]
        params = {p["key"]: p["value"] for p in fetched["data"]["params"]}
        metrics = {m["key"]: (m["value"], m["step"]) for m in fetched["data"]["metrics"]}
        tags = {t["key"]: t["value"] for t in fetched["data"]["tags"]}
        assert fetched["info"]["status"] == "FINISHED"
        assert params["model.lr"] == "0.01"
        assert params["logger.tracking_uri"] == base
        assert metrics["mota"] == (0.75, 3)
        assert len(tags[mlflow_log.GIT_COMMIT_TAG]) == 40
        query = urllib.parse.urlencode({"run_id": run_id})
        listed = get_json(f"{base}/api/2.0/mlflow/artifacts/list?{query}")
        assert {f["path"] for f in listed["files"]} == {"config.yaml", "video"}
        query = urllib.parse.urlencode({"run_id": run_id, "path": "video"})
        listed = get_json(f"{base}/api/2.0/mlflow/artifacts/list?{query}")
        assert [f["path"] for f in listed["files"]] == ["video/clip.txt"]
        # The server proxied the upload into its artifacts destination.
        assert [p.name for p in (tmp_path / "art").rglob("clip.txt")] == ["clip.txt"]
    finally:
        os.killpg(server.pid, signal.SIGTERM)
        try:
            server.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(server.pid, signal.SIGKILL)
            server.wait()


def test_artifact_file_is_the_stored_file_or_one_kept_download(
    config_dir: Path, store: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=artifacts")
    weights = tmp_path / "best.pt"
    weights.write_bytes(b"weights")
    with mlflow_log.start_run(cfg, run_name="w") as run:
        mlflow_log.log_artifact_file(weights, artifact_path="weights")
    run_id = run.info.run_id
    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))  # where a download would leave its copy
    local = mlflow_log.artifact_file(run_id, "weights/best.pt", tracking_uri=store)
    # a local store: its own file, nothing copied anywhere
    assert local.read_bytes() == b"weights" and local.parent.parent.name == "artifacts"
    assert list(scratch.iterdir()) == []
    # any other store: downloaded once into outputs/mlflow_artifacts/<run>/ and reused
    monkeypatch.setattr(mlflow_log, "REPO_ROOT", tmp_path / "repo")
    monkeypatch.setattr(
        mlflow_log, "urlparse", lambda uri: urllib.parse.urlparse("mlflow-artifacts:/elsewhere")
    )
    kept = mlflow_log.artifact_file(run_id, "weights/best.pt", tracking_uri=store)
    assert kept == tmp_path / "repo" / "outputs" / "mlflow_artifacts" / run_id / "weights" / "best.pt"
    assert kept.read_bytes() == b"weights"
    assert [p.name for p in kept.parent.iterdir()] == ["best.pt"]  # no scratch folder left beside it
    kept.write_bytes(b"kept")
    assert mlflow_log.artifact_file(run_id, "weights/best.pt", tracking_uri=store).read_bytes() == b"kept"


def test_a_sweep_job_is_named_after_its_swept_values(
    config_dir: Path, store: str, monkeypatch: pytest.MonkeyPatch
) -> None:
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=names", "model.lr=0.2")
    with mlflow_log.start_run(cfg, run_name="sweep") as parent:
        pass
    monkeypatch.setenv(mlflow_log.SWEPT_ENV, "model.lr,model.layers")
    with mlflow_log.start_run(cfg, run_name="fold3", parent_run_id=parent.info.run_id) as child:
        pass
    with mlflow_log.start_run(cfg, run_name="alone") as alone:  # not a job of the sweep
        pass
    client = mlflow.MlflowClient()
    logged = client.get_run(child.info.run_id)
    assert logged.info.run_name == "lr=0.2 layers=[1, 2]"
    assert logged.data.tags["swept"] == "model.lr,model.layers"
    assert logged.data.tags["model.lr"] == logged.data.params["model.lr"] == "0.2"
    assert client.get_run(alone.info.run_id).info.run_name == "alone"
    assert "swept" not in client.get_run(alone.info.run_id).data.tags
    assert mlflow_log.point_name({"a.lr": "1", "b.lr": "2"}) == "a.lr=1 b.lr=2"


def test_ui_links_and_pinned_columns(config_dir: Path, store: str, monkeypatch: pytest.MonkeyPatch) -> None:
    from spacetrack import mlflow_ui

    monkeypatch.setenv("PORT", "5099")
    assert mlflow_ui.ui_base(store) == "http://127.0.0.1:5099"
    assert mlflow_ui.ui_base("http://tracking.example:5000/") == "http://tracking.example:5000"
    # the runs route itself: the bare experiment route redirects to it and drops the view's key
    assert mlflow_ui.runs_view_url("7", "v1", "http://h:1") == (
        "http://h:1/#/experiments/7/runs?workflowType=machine_learning&viewStateShareKey=v1"
    )
    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=views")
    with mlflow_log.start_run(cfg, run_name="scored") as run:
        mlflow_log.log_metrics_step({"mota": 0.5, "idf1": 0.6, "num_frames": 9.0}, step=0)
    assert mlflow_ui.last_run_url() == (
        f"http://127.0.0.1:5099/#/experiments/{run.info.experiment_id}/runs/{run.info.run_id}"
        f" (serve that store with: MLFLOW_TRACKING_URI={store} make ui)"
    )
    links = dict(mlflow_ui.pin_views(store))
    experiment = mlflow.MlflowClient().get_experiment(run.info.experiment_id)
    assert links["views"] == mlflow_ui.runs_view_url(experiment.experiment_id, mlflow_ui.DEFAULT_VIEW, store)
    # the envelope the UI's "Save view" writes: listed under "Views" by name, the state as a JSON string
    envelope = json.loads(experiment.tags[mlflow_ui.VIEW_TAG + mlflow_ui.DEFAULT_VIEW])
    assert envelope["name"] == mlflow_ui.DEFAULT_VIEW_NAME and isinstance(envelope["createdAt"], int)
    view = json.loads(envelope["state"])
    assert view == mlflow_ui.load_view(experiment.tags, mlflow_ui.DEFAULT_VIEW)
    assert view["selectedColumns"] == ["metrics.`mota`", "metrics.`idf1`"]  # headline metrics it logged
    assert view["orderByKey"] == "attributes.start_time" and view["orderByAsc"] is False
    assert view["columnOrder"] == [mlflow_ui.RUN_NAME_COLUMN, "metrics.`mota`", "metrics.`idf1`"]
    assert view["columnWidths"] == {mlflow_ui.RUN_NAME_COLUMN: mlflow_ui.NAME_WIDTH[0]}  # "scored" is short


def test_a_sweep_view_is_named_after_the_sweep_and_fits_its_names(config_dir: Path, store: str) -> None:
    from spacetrack import mlflow_ui

    cfg = make_cfg(config_dir, f"logger.tracking_uri={store}", "logger.experiment=sweep_view")
    swept = {"swept": "tracker.max_age,tracker.n_init"}
    with mlflow_log.start_run(cfg, run_name="sweep", tags=swept) as parent:
        pass
    long_name = "max_age=30 n_init=3" * 3
    with mlflow_log.start_run(cfg, run_name=long_name, parent_run_id=parent.info.run_id):
        pass
    client = mlflow.MlflowClient()
    key, experiment_id = parent.info.run_id, parent.info.experiment_id
    columns = ["params.`tracker.max_age`", "metrics.`mota`", "params.`tracker.n_init`", "metrics.`idf1`"]
    only_points = f"tags.`{mlflow_log.PARENT_RUN_TAG}` = '{key}'"
    mlflow_ui.save_view(client, experiment_id, key, columns=columns, search_filter=only_points)
    envelope = json.loads(client.get_experiment(experiment_id).tags[mlflow_ui.VIEW_TAG + key])
    assert envelope["name"].startswith("sweep ") and envelope["name"].endswith(": max_age x n_init")
    view = mlflow_ui.load_view(client.get_experiment(experiment_id).tags, key)
    assert view["selectedColumns"] == columns and view["searchFilter"] == only_points
    # metrics first, as the table groups them, then params; the name column as wide as the points' names
    assert view["columnOrder"] == [mlflow_ui.RUN_NAME_COLUMN, *columns[1::2], *columns[::2]]
    width = view["columnWidths"][mlflow_ui.RUN_NAME_COLUMN]
    assert mlflow_ui.NAME_WIDTH[0] < width <= mlflow_ui.NAME_WIDTH[1] and width >= 5 * len(long_name)
    assert view["columnWidths"]["params.`tracker.max_age`"] >= 100
    # saved again under another name: created at the same time as before
    mlflow_ui.save_view(client, experiment_id, key, columns=columns[:2], name="mine")
    again = json.loads(client.get_experiment(experiment_id).tags[mlflow_ui.VIEW_TAG + key])
    assert again["name"] == "mine" and again["createdAt"] == envelope["createdAt"]
    assert mlflow_ui.load_view({mlflow_ui.VIEW_TAG + "old": json.dumps(view)}, "old") == view  # bare state
