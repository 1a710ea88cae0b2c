"""The train_reid entry point on the real configs: one fold, determinism, fold runs under a CV parent."""

from __future__ import annotations

import json

import mlflow
import numpy as np
import pytest
import torch

from spacetrack.config import compose_config
from spacetrack.mlflow_log import PARENT_RUN_TAG, cv_parent_summary, start_run
from spacetrack.reid import Encoder, training
from spacetrack.train_reid import run


def overrides(dataset, out, *extra) -> list[str]:
    return [
        "train_reid=smoke",
        f"dataset={dataset}",
        f"output_dir={out}",
        "train_reid.crops.frame_stride=2",
        "train_reid.device=cpu",
        # plumbing, not Table 1: a 32x16 input keeps the network 16x cheaper
        "model.net.input_height=32",
        "model.net.input_width=16",
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


def test_fold_runs_are_children_of_the_cross_validation_parent(tiny_dataset, tmp_path) -> None:
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    base = overrides(tiny_dataset, tmp_path / "cv", f"logger.tracking_uri={uri}")
    with start_run(compose_config("train_reid", base), run_name="cross-validation") as parent:
        parent_id = parent.info.run_id
        for fold in (0, 1):
            run(compose_config("train_reid", [*base, f"fold={fold}", f"cv_parent_run_id={parent_id}"]))
        summary = cv_parent_summary(parent_id, ["rank1", "pair_same_below_0.1"])
    assert set(summary) == {"rank1_mean", "rank1_std", "pair_same_below_0.1_mean", "pair_same_below_0.1_std"}
    client = mlflow.MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("reid").experiment_id])
    children = [r for r in runs if r.data.tags.get(PARENT_RUN_TAG) == parent_id]
    assert sorted(r.info.run_name for r in children) == ["fold0", "fold1"]
    child = children[0]
    manifest = json.loads((tiny_dataset / "manifest.json").read_text())
    assert child.data.tags["data_content"] == manifest["content_hash"]  # which labels and frames it saw
    assert {"distances.png", "metrics.json", "weights"} <= {
        a.path for a in client.list_artifacts(child.info.run_id)
    }
    encoder = Encoder.from_mlflow(child.info.run_id, tracking_uri=uri, device="cpu")
    assert encoder(np.zeros((32, 32, 3), np.uint8), [[2, 2, 8, 8]]).shape == (1, 128)


def test_a_stopped_training_resumes_to_the_same_weights_in_the_same_run(
    tiny_dataset, tmp_path, monkeypatch
) -> None:
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    base = overrides(
        tiny_dataset, tmp_path / "out", "fold=1", "train_reid.fit.epochs=3", f"logger.tracking_uri={uri}"
    )
    unbroken = run(compose_config("train_reid", [*base, "output_dir=" + str(tmp_path / "unbroken")]))

    real_fit = training.fit

    def stop_after_two_epochs(*args, save_state, **kwargs):
        def save_then_maybe_stop(state):
            save_state(state)
            if state["epoch"] == 1:
                raise KeyboardInterrupt

        return real_fit(*args, save_state=save_then_maybe_stop, **kwargs)

    monkeypatch.setattr(training, "fit", stop_after_two_epochs)
    with pytest.raises(KeyboardInterrupt):
        run(compose_config("train_reid", base))
    monkeypatch.setattr(training, "fit", real_fit)
    fold = tmp_path / "out" / "fold1"
    assert (fold / "last.pt").is_file() and not (fold / "reid.pt").exists()
    with pytest.raises(ValueError, match=r"cannot resume .*last\.pt with other settings: .*lr"):
        run(compose_config("train_reid", [*base, "resume=auto", "train_reid.fit.lr=0.01"]))

    resumed = run(compose_config("train_reid", [*base, "resume=auto"]))
    assert resumed["rank1"] == unbroken["rank1"] and resumed["train_loss"] == unbroken["train_loss"]
    a, b = (
        torch.load(p / "fold1" / "reid.pt", weights_only=True)
        for p in (tmp_path / "unbroken", tmp_path / "out")
    )
    for key, value in a["model"].items():
        torch.testing.assert_close(b["model"][key], value, rtol=0, atol=0)
    client = mlflow.MlflowClient(uri)
    runs = client.search_runs([client.get_experiment_by_name("reid").experiment_id])
    assert len(runs) == 2  # the unbroken run and the stopped-then-resumed one, not a third
    (continued,) = [r for r in runs if r.data.tags.get("resumes") == "1"]
    assert continued.info.status == "FINISHED"
    assert [m.step for m in client.get_metric_history(continued.info.run_id, "train_loss")] == [0, 1, 2, 3]


def test_resume_without_a_checkpoint_starts_afresh(tiny_dataset, tmp_path) -> None:
    base = overrides(tiny_dataset, tmp_path / "a", "logger=none", "fold=1")
    metrics = run(compose_config("train_reid", [*base, "resume=auto"]))
    assert (tmp_path / "a" / "fold1" / "last.pt").is_file()
    assert 0.0 <= metrics["rank1"] <= 1.0
    (tmp_path / "a" / "fold1" / "last.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match=r"last\.pt is not a readable re-ID training checkpoint"):
        run(compose_config("train_reid", [*base, "resume=auto"]))


def test_resume_takes_null_auto_or_a_path_like_the_detector(tiny_dataset, tmp_path) -> None:
    base = overrides(tiny_dataset, tmp_path / "a", "logger=none", "fold=1")
    with pytest.raises(ValueError, match=r"resume must be null, auto or the path of a last\.pt, got True"):
        run(compose_config("train_reid", [*base, "resume=true"]))
    missing = tmp_path / "elsewhere" / "last.pt"
    with pytest.raises(FileNotFoundError, match=rf"resume={missing}: no such checkpoint"):
        run(compose_config("train_reid", [*base, f"resume={missing}"]))
    run(compose_config("train_reid", base))
    moved = tmp_path / "kept" / "last.pt"
    moved.parent.mkdir()
    (tmp_path / "a" / "fold1" / "last.pt").rename(moved)
    (tmp_path / "a" / "fold1" / "reid.pt").unlink()
    with pytest.raises(ValueError, match=r"cannot resume .*kept/last\.pt with other settings: .*lr"):
        run(compose_config("train_reid", [*base, f"resume={moved}", "train_reid.fit.lr=0.01"]))


def test_a_checkpoint_with_the_former_flat_settings_resumes_under_the_blocks(tiny_dataset, tmp_path) -> None:
    """Checkpoints written when `train_reid` was one flat block (no sync_bn yet) keep resuming."""
    cfg = compose_config("train_reid", overrides(tiny_dataset, tmp_path / "a", "logger=none", "fold=1"))
    settings = training.training_settings(cfg, 1)
    nested = settings["train_reid"]
    flat = {k: v for k, v in nested.items() if not isinstance(v, dict) or k == "augment"}
    for old, (block, key) in training.FLAT_KEYS.items():
        flat[old] = nested[block][key]
    del flat["sync_bn"]  # older than the key: trained without it
    path = tmp_path / "last.pt"

    def write(train_reid: dict) -> None:
        state = {"format": training.CHECKPOINT_FORMAT, "settings": {**settings, "train_reid": train_reid}}
        torch.save(state | {"epoch": 0}, path)

    write(flat)
    assert training.load_resume_state(path, settings)["epoch"] == 0
    write({**flat, "gallery_window": 7})
    with pytest.raises(ValueError, match=r"with other settings: .*window"):
        training.load_resume_state(path, settings)
