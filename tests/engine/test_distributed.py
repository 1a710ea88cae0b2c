"""The pieces of a distributed training that need no second process: shares of a batch, the device of
a process, the refusals, the SLURM environment, the launcher preset."""

from __future__ import annotations

import os

import pytest
import torch
from torch.utils.data import RandomSampler

from detector_helpers import tiny_model
from spacetrack.config import compose_config
from spacetrack.engine import distributed
from spacetrack.engine.checkpoint import checkpoint_settings, settings_differences
from spacetrack.engine.distributed import World, batches_per_epoch, shard_of_batches

TWO = [World(rank=0, size=2), World(rank=1, size=2)]
TORCH_VARIABLES = ("RANK", "WORLD_SIZE", "LOCAL_RANK", "LOCAL_WORLD_SIZE", "MASTER_ADDR", "MASTER_PORT")


def test_one_process_keeps_the_order_and_every_batch():
    order = [5, 3, 9, 0, 1, 7, 2, 8, 4, 6, 10]
    assert shard_of_batches(order, batch_size=4, world=World(), drop_last=False) == order
    assert shard_of_batches(order, batch_size=4, world=World(), drop_last=True) == order[:8]
    assert batches_per_epoch(11, batch_size=4, world=World()) == 3


def test_each_process_takes_its_consecutive_share_of_every_batch():
    shares = [shard_of_batches(range(11), batch_size=4, world=w, drop_last=False) for w in TWO]
    assert shares == [[0, 1, 4, 5, 8, 9], [2, 3, 6, 7, 10]]  # the last batch of 3: 2 and 1
    assert [shard_of_batches(range(11), batch_size=4, world=w, drop_last=True) for w in TWO] == [
        [0, 1, 4, 5],
        [2, 3, 6, 7],
    ]
    # A last batch with fewer images than processes is left out (documented rounding).
    assert [shard_of_batches(range(9), batch_size=4, world=w, drop_last=False) for w in TWO] == [
        [0, 1, 4, 5],
        [2, 3, 6, 7],
    ]
    assert batches_per_epoch(9, batch_size=4, world=TWO[0]) == 2
    assert batches_per_epoch(10, batch_size=4, world=TWO[0]) == 3


def test_sharded_sampler_of_one_process_draws_as_the_random_sampler():
    ours, theirs = torch.Generator().manual_seed(4), torch.Generator().manual_seed(4)
    sampler = distributed.ShardedRandomSampler(
        10, batch_size=4, world=World(), generator=ours, drop_last=False
    )
    for _ in range(2):  # two epochs: the generator advances the same way
        assert list(sampler) == list(RandomSampler(range(10), generator=theirs))
    assert torch.equal(ours.get_state(), theirs.get_state())
    assert (
        len(distributed.ShardedRandomSampler(10, batch_size=4, world=TWO[1], generator=ours, drop_last=True))
        == 4
    )


def test_a_batch_the_processes_cannot_split_evenly_is_refused():
    with pytest.raises(
        ValueError, match=r"train.trainer.batch_size=9 is the global batch.*2 processes.*8 or 10"
    ):
        distributed.check_batch_split(9, TWO[0], key="train.trainer.batch_size")
    assert distributed.check_batch_split(8, TWO[1], key="train.trainer.batch_size") == 4


def test_more_processes_than_gpus_are_refused(monkeypatch):
    four = World(rank=0, size=4, local_size=4)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(
        ValueError, match=r"4 training processes .* need 4 GPUs, but it has none; train.trainer.device=cpu"
    ):
        distributed.process_device("auto", four, key="train.trainer.device")
    assert distributed.process_device("cpu", four, key="train.trainer.device") == torch.device("cpu")
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch.cuda, "device_count", lambda: 2)
    with pytest.raises(
        ValueError,
        match=r"4 training processes on this machine \(GPUS / --nproc_per_node\) need 4 GPUs, but it has 2$",
    ):
        distributed.process_device("cuda", four, key="train.trainer.device")
    with pytest.raises(ValueError, match="cuda:1 pins one GPU, but each of the 4 processes takes its own"):
        distributed.process_device("cuda:1", four, key="train.trainer.device")


def test_make_checks_gpus_before_starting_processes(monkeypatch, capsys):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    for gpus, message in (
        ("2", "2 training processes on this machine (GPUS / --nproc_per_node) need 2 GPUs, but it has none; "
              "train_reid.device=cpu trains in 2 CPU processes instead"),
        ("0", "GPUS=0: expected a number of GPUs, 1 or more"),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as stop:
            distributed.main([gpus, "train_reid.device"])
        assert stop.value.code == 2
        assert capsys.readouterr().err == f"spacetrack: error: {message}\n"


def test_sync_bn_needs_gpu_processes():
    with pytest.raises(ValueError, match="sync_bn=true needs GPU processes"):
        distributed.distribute_model(tiny_model(), torch.device("cpu"), TWO[0], sync_bn=True)
    model = tiny_model()
    assert distributed.distribute_model(model, torch.device("cpu"), World(), sync_bn=True) is model


def test_a_slurm_job_of_several_tasks_gives_each_its_rank(monkeypatch):
    for name in TORCH_VARIABLES:
        monkeypatch.setenv(name, "")  # restored (removed) after the test, whatever the export sets
        monkeypatch.delenv(name)
    slurm = {"SUBMITIT_EXECUTOR": "slurm", "SLURM_JOB_ID": "4242", "SLURM_NTASKS": "8", "SLURM_JOB_NUM_NODES": "2",
             "SLURM_NODEID": "1", "SLURM_JOB_NODELIST": "gpu[07-08]", "SLURM_PROCID": "5", "SLURM_LOCALID": "1"}  # fmt: skip
    for name, value in slurm.items():
        monkeypatch.setenv(name, value)
    assert distributed.launched_world() == World(rank=5, size=8, local_rank=1, local_size=4)
    assert os.environ["MASTER_ADDR"] == "gpu07" and os.environ["MASTER_PORT"].isdigit()


def test_the_slurm_preset_starts_a_task_per_gpu():
    cfg = compose_config(
        "train", ["hydra/launcher=slurm", "hydra.launcher.gpus_per_node=4"], return_hydra_config=True
    )
    assert cfg.hydra.launcher.tasks_per_node == 4 and cfg.hydra.launcher.nodes == 1


def test_checkpoints_older_than_sync_bn_and_freeze_resume_as_trained_without_them():
    older = {"sync_bn": False, "freeze": 0, "lr0": 0.01}
    assert checkpoint_settings({"settings": {"lr0": 0.01}}) == older
    assert checkpoint_settings({"settings": {"sync_bn": True, "freeze": 5}}) == {"sync_bn": True, "freeze": 5}
    # either side may lack a later setting: it counts as its earlier value
    assert settings_differences({"settings": {"lr0": 0.01}}, {"lr0": 0.01, "freeze": 0}) == ""
    assert settings_differences({"settings": {"lr0": 0.01, "freeze": 0}}, {"lr0": 0.01}) == ""
    assert settings_differences({"settings": {"freeze": 3}}, {}) == "freeze: checkpoint 3, configured 0"
