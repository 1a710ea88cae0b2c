"""The train_reid entry point on the real configs: one fold, determinism, and a logged cross-validation."""

from __future__ import annotations

import json

import mlflow
import numpy as np
import torch

from spacetrack.config import compose_config
from spacetrack.mlflow_log import PARENT_RUN_TAG
from spacetrack.reid import Encoder
from spacetrack.train_reid import run


def overrides(dataset, out, *extra) -> list[str]:
    return [
        "train_reid=smoke",
        f"dataset={dataset}",
        f"output_dir={out}",
        "train_reid.frame_stride=2",
        "train_reid.device=cpu",
        *extra,
    ]


def test_one_fold_writes_weights_metrics_and_plot_deterministically(tiny_dataset, tmp_path) -> None:
    cfg = compose_config("train_reid", overrides(tiny_dataset, tmp_path / "a", "logger=none", "fold=1"))
    assert cfg.logger.experiment == "reid"
    metrics = run(cfg)
    fold = tmp_path / "a" / "fold1"
    assert {p.name for p in fold.iterdir()} >= {"reid.pt", "metrics.json", "distances.png", "distances.npz"}
    assert json.loads((fold / "metrics.json").read_text())["rank1"] == metrics["rank1"]
    assert metrics["train_identities"] == 4 and metrics["val_identities"] == 3  # static 1000 trains only
    assert 0.0 <= metrics["pair_same_below_0.1"] <= 1.0
    again = run(
        compose_config("train_reid", overrides(tiny_dataset, tmp_path / "b", "logger=none", "fold=1"))
    )
    assert again == {
        **metrics,
        "crop_seconds": again["crop_seconds"],
        "train_seconds": again["train_seconds"],
    }
    a, b = (torch.load(p / "fold1" / "reid.pt", weights_only=True) for p in (tmp_path / "a", tmp_path / "b"))
    for key, value in a["model"].items():
        torch.testing.assert_close(b["model"][key], value, rtol=0, atol=0)


def test_cross_validation_logs_parent_and_fold_runs(tiny_dataset, tmp_path) -> None:
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cfg = compose_config(
        "train_reid", overrides(tiny_dataset, tmp_path / "cv", f"logger.tracking_uri={uri}", "cv=true")
    )
    summary = run(cfg)
    assert set(summary) >= {"rank1_mean", "rank1_std", "mAP_mean", "pair_same_below_0.1_mean"}
    client = mlflow.MlflowClient(uri)
    experiment = client.get_experiment_by_name("reid")
    runs = client.search_runs([experiment.experiment_id])
    parent = next(r for r in runs if r.info.run_name == "cv")
    children = [r for r in runs if r.data.tags.get(PARENT_RUN_TAG) == parent.info.run_id]
    assert sorted(r.info.run_name for r in children) == ["fold0", "fold1"]
    assert parent.data.metrics["rank1_mean"] == summary["rank1_mean"]
    child = children[0]
    artifacts = {a.path for a in client.list_artifacts(child.info.run_id)}
    assert {"distances.png", "metrics.json", "weights"} <= artifacts
    encoder = Encoder.from_mlflow(child.info.run_id, tracking_uri=uri, device="cpu")
    frame = np.zeros((32, 32, 3), np.uint8)
    assert encoder(frame, [[2, 2, 8, 8]]).shape == (1, 128)
