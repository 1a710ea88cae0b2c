"""The re-ID training in two CPU processes on gloo, against one process with the same global batch.

One spawn of two processes does every distributed run: an unbroken toy fit, one killed after an
epoch's checkpoint and resumed, and a fold from the real config with the writes of each process
counted. The toy network has no BatchNorm and no dropout, whose draws are per process by nature
(BatchNorm statistics over a process's share, without SyncBatchNorm), so two processes must give
one process's losses and weights to float32 rounding.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch
import torch.distributed as dist
from torch.utils.data import TensorDataset

from ddp_helpers import count_calls, run_in_processes
from reid_helpers import Toy, toy_points
from spacetrack.config import compose_config
from spacetrack.engine import distributed
from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.io import load_torch_file
from spacetrack.reid.loss import CosineSoftmax
from spacetrack.reid.train import fit, shuffled_loader

EPOCHS, KILL_AT_EPOCH = 6, 3
RTOL, ATOL = 1e-4, 1e-6  # float32 sums of a batch in one piece against two shares and an all-reduce


class Crops(TensorDataset):
    """60 noisy one-hot points of 3 identities; raises KeyboardInterrupt in epoch `kill_at` (the
    training sets `epoch` before each epoch)."""

    def __init__(self, kill_at: int | None = None) -> None:
        super().__init__(*toy_points(torch.Generator().manual_seed(1)))
        self.epoch, self.kill_at = 0, kill_at

    def __getitem__(self, index: int):
        if self.epoch == self.kill_at:
            raise KeyboardInterrupt
        return super().__getitem__(index)


def toy_fit(*, kill_at: int | None = None, resume: dict | None = None, save_to: Path | None = None):
    """A fit of the toy network over 5 global batches of 12 a epoch; (epoch stats, net, head)."""
    torch.manual_seed(0)
    net, head = Toy(), CosineSoftmax(feature_dim=3, num_classes=3)
    loader = shuffled_loader(Crops(kill_at), batch_size=12, seed=0)
    stats: list[dict] = []
    fit(net, head, loader, epochs=EPOCHS, lr=0.05, weight_decay=0.01, warmup_epochs=1, device=torch.device("cpu"),
        on_epoch=lambda epoch, s: stats.append(s),
        save_state=(lambda state: save_checkpoint(save_to, state)) if save_to else None,
        resume_state=resume)  # fmt: skip
    return stats, net, head


def fold_overrides(dataset: Path, out: Path) -> list[str]:
    return ["train_reid=smoke", f"dataset={dataset}", f"output_dir={out}", "train_reid.device=cpu",
            "train_reid.crops.frame_stride=2", "train_reid.batch_size=4", "model.net.input_height=32",
            "model.net.input_width=16", "logger=none", "fold=1"]  # fmt: skip


def distributed_worker(dataset: Path, out: Path) -> None:
    """In each of the two processes: the toy fits and the real fold; results to `out/rank<r>.json`."""
    from spacetrack.reid import training

    with distributed.process_group("cpu", key="device") as world:
        stats, net, head = toy_fit(save_to=out / "unbroken.pt")
        checkpoint = out / "killed.pt"
        with pytest.raises(KeyboardInterrupt):
            toy_fit(kill_at=KILL_AT_EPOCH, save_to=checkpoint)
        dist.barrier()  # rank 0 has written the checkpoint of the epoch before
        killed_epoch = load_torch_file(checkpoint, "state")["epoch"]
        _, resumed, _ = toy_fit(resume=load_torch_file(checkpoint, "state"), save_to=checkpoint)
        writes = count_calls(
            [
                (training, name)
                for name in ("start_run", "save_checkpoint", "save_weights", "atomic_write_text")
            ]
        )
        metrics = training.train_fold(compose_config("train_reid", fold_overrides(dataset, out / "fold")), 1)
    report = {
        "stats": stats,
        "weight": net.linear.weight.tolist(),
        "scale": float(head.scale.detach()),
        "killed_epoch": killed_epoch,
        "resumed_weight": resumed.linear.weight.tolist(),
        "writes": writes,
        "metrics": metrics,
    }
    (out / f"rank{world.rank}.json").write_text(json.dumps(report))


@pytest.fixture(scope="module")
def runs(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("reid_ddp")
    run_in_processes(distributed_worker, 2, tiny_dataset, out)
    return out, [json.loads((out / f"rank{r}.json").read_text()) for r in (0, 1)]


def test_two_processes_give_the_losses_and_weights_of_one(runs):
    _, (zero, one) = runs
    stats, net, head = toy_fit()
    assert len(zero["stats"]) == EPOCHS and one["stats"] == []  # rank 0 alone reports
    for shared, single in zip(zero["stats"], stats, strict=True):
        assert shared == pytest.approx(single, rel=RTOL)
    expected = net.linear.weight.detach()
    torch.testing.assert_close(torch.tensor(zero["weight"]), expected, rtol=RTOL, atol=ATOL)
    torch.testing.assert_close(torch.tensor(one["weight"]), expected, rtol=RTOL, atol=ATOL)
    assert zero["scale"] == pytest.approx(float(head.scale.detach()), rel=RTOL)
    assert (expected - Toy().linear.weight).abs().max() > 1000 * ATOL  # it did train


def test_a_killed_two_process_fit_resumes_to_the_unbroken_weights(runs):
    out, (zero, one) = runs
    assert zero["killed_epoch"] == KILL_AT_EPOCH - 1
    assert zero["resumed_weight"] == zero["weight"] and one["resumed_weight"] == one["weight"]
    assert load_torch_file(out / "killed.pt", "state")["stats"] == zero["stats"][-1]


def test_only_rank_0_writes_the_fold_and_its_run(runs):
    out, (zero, one) = runs
    assert all(count > 0 for count in zero["writes"].values()), zero["writes"]
    assert all(count == 0 for count in one["writes"].values()), one["writes"]
    assert {p.name for p in (out / "fold" / "fold1").iterdir()} >= {"reid.pt", "last.pt", "metrics.json"}
    assert one["metrics"] == zero["metrics"] and "rank1" in zero["metrics"]


def test_batch_not_split_evenly_is_refused():
    with pytest.raises(
        ValueError, match=r"train_reid.batch_size=10 is the global batch.*3 processes.*9 or 12"
    ):
        distributed.check_batch_split(10, distributed.World(rank=0, size=3), key="train_reid.batch_size")
