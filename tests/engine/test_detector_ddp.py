"""The detector trained by two CPU processes on gloo, against one process with the same global batch.

One spawn of two processes does every distributed run (process start-up is most of the time):
an unbroken training, one killed mid-epoch and resumed, and a fold trained from the real config
with MLflow, with the writes of each process counted.

Without SyncBatchNorm (CUDA only) BatchNorm normalises over each process's share of the batch, and
YoloLoss averages its box and class terms over a batch's matched anchors, so the real network and
loss are not expected to give the one-process numbers. The comparison therefore uses a network with
per-image normalisation (GroupNorm) and YoloLoss taken image by image, for which the distributed maths
(shares of each batch, loss scaling, gradient averaging and accumulation) must reproduce one process
to float32 rounding.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import mlflow
import pytest
import torch
from omegaconf import open_dict
from torch import nn
from torch.utils.data import Dataset

from ddp_helpers import count_calls, run_in_processes
from detector_helpers import loss_for, tiny_model, write_tiny_dataset
from spacetrack.config import compose_config
from spacetrack.data.yolo_dataset import YoloDataset
from spacetrack.engine import distributed
from spacetrack.engine.checkpoint import load_checkpoint
from spacetrack.engine.trainer import Trainer

SIZE = 64
# 11 images in batches of 4, 4 and 3 (shares 2+2, 2+2 and 2+1); two batches per optimiser step.
SETTINGS = {"epochs": 2, "batch_size": 4, "nbs": 8, "warmup_epochs": 0.5, "ema_tau": 5.0, "device": "cpu",
            "amp": False, "progress": False, "checkpoint_minutes": None}  # fmt: skip
KILL_AT = 6  # the training call of epoch 1's last batch: after the mid-epoch checkpoint of its first step
# float32 sums in another order (a batch in one piece against two shares and an all-reduce)
RTOL, ATOL = 1e-4, 1e-6


class FirstImages(Dataset):
    """The first `count` samples of a YoloDataset (an odd number, for unequal shares)."""

    def __init__(self, dataset: YoloDataset, count: int) -> None:
        self.dataset, self.count = dataset, count

    def set_epoch(self, epoch: int) -> None:
        self.dataset.set_epoch(epoch)

    def __len__(self) -> int:
        return self.count

    def __getitem__(self, index: int):
        return self.dataset[index]


class PerImageLoss:
    """YoloLoss image by image, summed: the trainer's contract (the total is the per-image mean times
    the images; [box, obj, cls] per image) with a total that splits exactly over shares of a batch.
    Records the total of every training call; raises KeyboardInterrupt at training call `kill_at`."""

    def __init__(self, kill_at: int | None = None) -> None:
        self.inner = loss_for(tiny_model(), SIZE)
        self.kill_at, self.totals = kill_at, []

    def __call__(self, raw, targets):
        totals, parts = [], []
        for i in range(raw[0].shape[0]):
            rows = targets[targets[:, 0] == i].clone()
            rows[:, 0] = 0
            total, part = self.inner([p[i : i + 1] for p in raw], rows)
            totals.append(total)
            parts.append(part)
        total = torch.stack(totals).sum()
        if raw[0].requires_grad:  # training, not validation
            self.totals.append(total.item())
            if len(self.totals) == self.kill_at:
                raise KeyboardInterrupt
        return total, torch.stack(parts).mean(0)


def per_image_model() -> nn.Module:
    """The tiny YOLOv5 at its seeded start with every BatchNorm replaced by per-image GroupNorm."""
    torch.manual_seed(0)
    model = tiny_model()
    for module in list(model.modules()):
        for name, child in module.named_children():
            if isinstance(child, nn.BatchNorm2d):
                setattr(module, name, nn.GroupNorm(1, child.num_features, eps=child.eps))
    return model


def datasets(root: Path) -> tuple[Dataset, YoloDataset]:
    names = [f"seq_{i:03d}_nominal" for i in range(9)]
    train = YoloDataset(root=root, sequences=names[1:4], num_classes=3, image_size=SIZE, seed=3)
    val = YoloDataset(root=root, sequences=names[:1], num_classes=3, image_size=SIZE)
    return FirstImages(train, 11), val


def fit(root: Path, out_dir: Path, loss: PerImageLoss, resume_from: Path | None = None, **overrides) -> dict:
    train, val = datasets(root)
    model = per_image_model()
    trainer = Trainer(**{**SETTINGS, **overrides})
    return trainer.fit(
        model=model, loss_fn=loss, train_set=train, val_set=val, out_dir=out_dir, resume_from=resume_from
    )


def fold_config(root: Path, out_dir: Path, uri: str):
    cfg = compose_config(
        "train",
        [
            "train=smoke",
            "logger=mlflow",
            f"logger.tracking_uri={uri}",
            f"data_root={root.parent}",
            f"data.name={root.name}",
            f"output_dir={out_dir}",
            "fold=3",
            "weights=none",
            "model.width_multiple=0.125",
            "train.frame_stride=4",
            "train.trainer.device=cpu",
            "train.trainer.progress=false",
        ],
    )
    with open_dict(cfg):
        cfg.cv_parent_run_id = None
    return cfg


def distributed_worker(root: Path, out: Path) -> None:
    """In each of the two processes: the unbroken run, the killed and resumed run, the fold from the
    real config; what each process saw goes to `out/rank<r>.json` (outside the training folders)."""
    from spacetrack.engine import trainer as trainer_module
    from spacetrack.engine import training as training_module

    with distributed.process_group("cpu", key="device") as world:
        unbroken = PerImageLoss()
        fit(root, out / "unbroken", unbroken)
        with pytest.raises(KeyboardInterrupt):
            fit(root, out / "killed", PerImageLoss(kill_at=KILL_AT), checkpoint_minutes=0)
        if world.is_main:
            shutil.copy(out / "killed" / "weights" / "last.pt", out / "killed_last.pt")
        last = out / "killed" / "weights" / "last.pt"
        resumed = fit(root, out / "killed", PerImageLoss(), resume_from=last, checkpoint_minutes=0)

        writes = count_calls(
            [(trainer_module, "save_checkpoint"), (training_module, "start_run"), (training_module, "write_image"),
             (mlflow, "log_metrics"), (mlflow, "log_artifact"), (mlflow, "log_params")]
        )  # fmt: skip
        fold = training_module.train_fold(
            fold_config(root, out / f"fold_rank{world.rank}", f"sqlite:///{out / 'mlflow.db'}")
        )
    report = {
        "world": [world.rank, world.size],
        "losses": unbroken.totals,
        "resumed_history": [r["box"] for r in resumed["history"]],
        "writes": writes,
        "fold_metrics": fold["metrics"],
        "fold_last": str(fold["last"]),
    }
    (out / f"rank{world.rank}.json").write_text(json.dumps(report))


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The two-process runs and the one-process reference, on the same data."""
    root = write_tiny_dataset(tmp_path_factory.mktemp("data") / "tiny")
    out = tmp_path_factory.mktemp("ddp")
    run_in_processes(distributed_worker, 2, root, out)
    single_loss = PerImageLoss()
    single = fit(root, out / "single", single_loss)
    reports = [json.loads((out / f"rank{r}.json").read_text()) for r in (0, 1)]
    return {
        "root": root,
        "out": out,
        "single": single,
        "single_losses": single_loss.totals,
        "reports": reports,
    }


def assert_same_weights(a: dict, b: dict, **tolerance) -> None:
    for key in ("model", "ema"):
        for name, value in a[key].items():
            torch.testing.assert_close(
                b[key][name], value, msg=lambda m, k=f"{key}.{name}": f"{k}: {m}", **tolerance
            )


def test_two_processes_give_the_losses_and_weights_of_one(runs):
    zero, one = runs["reports"]
    assert zero["world"] == [0, 2] and one["world"] == [1, 2]
    # Every training call of the one-process run is one batch; the two shares of it add up to it.
    assert len(zero["losses"]) == len(one["losses"]) == len(runs["single_losses"]) == 6
    summed = [a + b for a, b in zip(zero["losses"], one["losses"], strict=True)]
    assert summed == pytest.approx(runs["single_losses"], rel=RTOL)
    assert one["losses"][2] < 0.6 * zero["losses"][2]  # the last batch's shares: 2 images and 1
    single = load_checkpoint(runs["single"]["last"])
    shared = load_checkpoint(runs["out"] / "unbroken" / "weights" / "last.pt")
    assert shared["world_size"] == 2 and single["world_size"] == 1
    assert_same_weights(single, shared, rtol=RTOL, atol=ATOL)
    # The weights did move, by far more than the tolerance.
    start = per_image_model().state_dict()
    moved = max(
        (single["model"][k] - v).abs().max().item() for k, v in start.items() if v.is_floating_point()
    )
    assert moved > 1000 * ATOL
    assert [r["box"] for r in shared["history"]] == pytest.approx(
        [r["box"] for r in single["history"]], rel=RTOL
    )


def test_a_killed_two_process_run_resumes_to_the_unbroken_weights(runs):
    killed = load_checkpoint(runs["out"] / "killed_last.pt")
    assert killed["epoch"] == 0 and killed["partial"]["batch"] == 2
    unbroken = load_checkpoint(runs["out"] / "unbroken" / "weights" / "last.pt")
    resumed = load_checkpoint(runs["out"] / "killed" / "weights" / "last.pt")
    assert_same_weights(unbroken, resumed, rtol=0, atol=0)
    assert runs["reports"][0]["resumed_history"] == pytest.approx([r["box"] for r in unbroken["history"]])


def test_a_two_process_checkpoint_resumes_in_one_process(runs, tmp_path, capsys):
    shutil.copytree(runs["out"] / "killed", tmp_path / "run")
    last = tmp_path / "run" / "weights" / "last.pt"
    shutil.copy(runs["out"] / "killed_last.pt", last)
    fit(runs["root"], tmp_path / "run", PerImageLoss(), resume_from=last, checkpoint_minutes=0)
    assert f"resuming {last}, trained in 2 process(es), in 1" in capsys.readouterr().out
    unbroken = load_checkpoint(runs["out"] / "unbroken" / "weights" / "last.pt")
    assert_same_weights(unbroken, load_checkpoint(last), rtol=RTOL, atol=ATOL)


def test_only_rank_0_writes_checkpoints_plots_and_mlflow(runs):
    zero, one = runs["reports"]
    assert all(count > 0 for count in zero["writes"].values()), zero["writes"]
    assert all(count == 0 for count in one["writes"].values()), one["writes"]
    out = runs["out"]
    assert not (out / "fold_rank1").exists()
    assert (out / "fold_rank0" / "weights" / "best.pt").is_file()
    assert (out / "fold_rank0" / "plots" / "pr_curve.png").is_file()
    # Both processes return rank 0's results; the store holds one run.
    assert one["fold_metrics"] == zero["fold_metrics"] and one["fold_last"] == zero["fold_last"]
    client = mlflow.MlflowClient(f"sqlite:///{out / 'mlflow.db'}")
    (run,) = client.search_runs([client.get_experiment_by_name("detector").experiment_id])
    assert run.data.metrics["best_fitness"] == pytest.approx(zero["fold_metrics"]["fitness"])
