"""The sweep report: which keys were swept, the MOTA heatmap and the table."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import mlflow
import pytest

from spacetrack import mlflow_ui
from spacetrack.config import REPO_ROOT
from spacetrack.mlflow_log import NOTE_TAG, PARENT_RUN_TAG
from spacetrack.pipeline.sweep import SweepCallback, plot_sweep, sweep_table, swept_keys

STATIC_SEQ = "seq_005_static_distractors"


def _points():
    return [
        {"overrides": {"fold": "3", "tracker.max_cosine_distance": c, "tracker.max_iou_distance": i},
         "metrics": {"mota": float(c) + float(i), "idf1": 0.5, "idsw": 1, "fp": 2, "fn": 3}}
        for c in ("0.1", "0.2") for i in ("0.3", "0.5", "0.7")
    ]  # fmt: skip


def test_swept_keys_leave_out_fixed_ones():
    keys = swept_keys([p["overrides"] for p in _points()])
    assert keys == ["tracker.max_cosine_distance", "tracker.max_iou_distance"]


def test_heatmap_table_and_report(tmp_path):
    points = _points()
    keys = swept_keys([p["overrides"] for p in points])
    assert plot_sweep(points, keys, "mota", tmp_path / "h.png") and (tmp_path / "h.png").stat().st_size > 0
    assert not plot_sweep(points, [], "mota", tmp_path / "none.png")
    table = sweep_table(points, keys, ["mota"])
    assert table.splitlines()[2] == "| 0.1 | 0.3 | 0.4 |"
    callback = SweepCallback(metric="mota")
    callback.points = points
    callback._report(tmp_path / "sweep")
    record = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    assert record["best"]["overrides"]["tracker.max_iou_distance"] == "0.7"
    assert record["best"]["overrides"]["tracker.max_cosine_distance"] == "0.2"
    assert (tmp_path / "sweep" / "heatmap.png").is_file() and (tmp_path / "sweep" / "sweep.md").is_file()


def test_a_sweep_over_folds_gets_bars_with_the_mean(tmp_path):
    points = [
        {"overrides": {"fold": str(k), "video": "false"}, "metrics": {"mota": 0.1 * k, "idf1": 0.5}}
        for k in range(3)
    ]
    callback = SweepCallback(metric="mota")
    callback.points = points
    callback._report(tmp_path / "cv")
    record = json.loads((tmp_path / "cv" / "sweep.json").read_text())
    assert record["swept"] == ["fold"]
    assert abs(record["mota_mean"] - 0.1) < 1e-9 and abs(record["mota_std"] - 0.0816497) < 1e-6
    assert (tmp_path / "cv" / "bars.png").stat().st_size > 0
    assert not (tmp_path / "cv" / "heatmap.png").exists()


def test_a_grid_sweep_reports_its_best_point_not_a_mean(tmp_path):
    callback = SweepCallback(metric="mota")
    callback.points = _points()
    callback._report(tmp_path / "sweep")
    record = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    assert record["mota_best"] == 0.2 + 0.7 and "mota_mean" not in record
    assert callback.headline() == "mota_best 0.9 at max_cosine_distance=0.2 max_iou_distance=0.7"


@pytest.mark.slow
def test_sweep_from_the_command_line_is_readable_in_mlflow(smoke_dataset, tmp_path):
    """The multirun a user types: children named by their values, the parent's best and description, the
    view of the points' table, and the summary line that links it."""
    store = f"sqlite:///{tmp_path / 'mlflow.db'}"
    sweep_dir = tmp_path / "multirun"
    result = subprocess.run(
        [
            sys.executable, "-m", "spacetrack.track", "-m", "tracker.max_iou_distance=0.3,0.9",
            "tracker.max_age=1,30", "data=smoke", f"data_root={smoke_dataset.parent}",
            f"cache.dir={tmp_path / 'cache'}", "detector=ground_truth", "reid.weights=none", "tracker=sort",
            f"sequence={STATIC_SEQ}", "max_frames=12", "video=false", "progress=false",
            f"logger.tracking_uri={store}", f"hydra.sweep.dir={sweep_dir}",
        ],
        capture_output=True, text=True, cwd=REPO_ROOT, timeout=1800,
        env={**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PORT": "5000"},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    assert "4/4" in result.stderr  # the bar over the sweep's jobs
    line = result.stdout.strip().splitlines()[-1]
    assert line.startswith("spacetrack track: mota_best ") and " at max_iou_distance=" in line
    assert f"| files: {sweep_dir} |" in line
    assert (sweep_dir / "sweep.md").is_file() and (sweep_dir / "heatmap.png").is_file()

    client = mlflow.MlflowClient(tracking_uri=store)
    experiment = client.get_experiment_by_name("track")
    runs = client.search_runs([experiment.experiment_id])
    (parent,) = [r for r in runs if r.info.run_name == "sweep"]
    children = [r for r in runs if r.data.tags.get(PARENT_RUN_TAG) == parent.info.run_id]
    names = {f"max_iou_distance={i} max_age={a}" for i in ("0.3", "0.9") for a in ("1", "30")}
    assert {c.info.run_name for c in children} == names
    child = children[0]
    assert child.data.tags["swept"] == "tracker.max_iou_distance,tracker.max_age"
    assert child.data.tags["tracker.max_age"] == child.data.params["tracker.max_age"]
    best = max(c.data.metrics["mota"] for c in children)
    assert parent.data.metrics["mota_best"] == best and "mota_mean" not in parent.data.metrics
    (named,) = [c for c in children if c.info.run_name == parent.data.tags["best"]]
    assert named.data.metrics["mota"] == best
    assert parent.data.params["best.tracker.max_age"] == named.data.params["tracker.max_age"]
    note = parent.data.tags[NOTE_TAG]
    assert "`tracker.max_iou_distance` over 0.3, 0.9" in note and f"sequence {STATIC_SEQ}" in note
    url = line.split("| MLflow: ")[1].split()[0]
    key = parent.info.run_id
    assert url == mlflow_ui.runs_view_url(experiment.experiment_id, key, store) and url in note
    view = mlflow_ui.load_view(client.get_experiment(experiment.experiment_id).tags, key)
    assert view["searchFilter"] == f"tags.`{PARENT_RUN_TAG}` = '{key}'"
    assert view["selectedColumns"][:3] == [
        "params.`tracker.max_iou_distance`", "params.`tracker.max_age`", "metrics.`mota`",
    ]  # fmt: skip
    shown = client.search_runs([experiment.experiment_id], filter_string=view["searchFilter"])
    assert {r.info.run_name for r in shown} == names
