import copy
import math

import pytest
import torch

from detector_helpers import loss_for, tiny_model, write_tiny_dataset
from spacetrack.data.yolo_dataset import YoloDataset, build_augmentation
from spacetrack.engine.checkpoint import load_checkpoint, load_detector, unfinished_checkpoint
from spacetrack.engine.optim import lr_factor
from spacetrack.engine.trainer import Trainer, planned_epochs

SIZE = 64
SETTINGS = {"epochs": 2, "batch_size": 4, "nbs": 4, "warmup_epochs": 0.5, "ema_tau": 5.0, "device": "cpu"}


def datasets(root):
    augment = build_augmentation(
        hue=5, saturation=20, value=20, fliplr=0.5, flipud=0.5, scale=0.2, translate=0.1
    )
    names = [f"seq_{i:03d}_nominal" for i in range(9)]
    train = YoloDataset(
        root=root, sequences=names[1:3], num_classes=3, image_size=SIZE, augment=augment, seed=3
    )
    val = YoloDataset(root=root, sequences=names[:1], num_classes=3, image_size=SIZE)
    return train, val


def fit(root, out_dir, *, resume_from=None, on_epoch_end=None, loss_fn=None, **overrides):
    torch.manual_seed(0)
    model = tiny_model()
    train, val = datasets(root)
    return Trainer(**{**SETTINGS, **overrides}).fit(
        model=model,
        loss_fn=loss_fn or loss_for(model, SIZE),
        train_set=train,
        val_set=val,
        out_dir=out_dir,
        resume_from=resume_from,
        on_epoch_end=on_epoch_end,
    )


@pytest.fixture(scope="module")
def straight_run(tmp_path_factory):
    """Two uninterrupted epochs, shared by the tests that only read their results."""
    root = write_tiny_dataset(tmp_path_factory.mktemp("data") / "tiny")
    return root, fit(root, tmp_path_factory.mktemp("straight"))


def test_smoke_training_writes_checkpoints_and_metrics(straight_run):
    _, result = straight_run
    assert [r["epoch"] for r in result["history"]] == [0, 1]
    assert result["planned_epochs"] == 2  # no time budget: every configured epoch
    for record in result["history"]:
        assert math.isfinite(record["box"] + record["obj"] + record["cls"])
        assert 0 <= record["map50_95"] <= record["map50"] <= 1
    assert result["best"].is_file() and result["last"].is_file()
    assert load_checkpoint(result["last"])["epoch"] == 1
    model = load_detector(result["best"])
    assert model.predict(torch.zeros(1, 3, SIZE, SIZE)).shape[-1] == 8


def test_resume_after_a_kill_matches_an_uninterrupted_run(straight_run, tmp_path):
    tiny_dataset, straight = straight_run

    def kill_after_first_epoch(record, details, is_best):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        fit(tiny_dataset, tmp_path / "killed", on_epoch_end=kill_after_first_epoch)
    resumed = fit(tiny_dataset, tmp_path / "killed", resume_from=tmp_path / "killed" / "weights" / "last.pt")
    a = load_checkpoint(straight["last"])
    b = load_checkpoint(resumed["last"])
    for key in ("model", "ema"):
        for name, value in a[key].items():
            assert torch.equal(value, b[key][name]), f"{key}.{name} differs after resume"
    assert a["history"][-1]["map50_95"] == b["history"][-1]["map50_95"]


def test_a_run_stopped_mid_epoch_resumes_from_the_batch_it_reached(straight_run, tmp_path):
    tiny_dataset, straight = straight_run
    real, calls = loss_for(tiny_model(), SIZE), {"n": 0}

    def stop_at_the_second_batch_of_epoch_1(raw, targets):
        # calls 1-2: epoch 0's two batches, 3: its validation, 4: epoch 1 batch 0, 5: epoch 1 batch 1
        calls["n"] += 1
        if calls["n"] == 5:
            raise KeyboardInterrupt
        return real(raw, targets)

    with pytest.raises(KeyboardInterrupt):
        fit(
            tiny_dataset,
            tmp_path / "stopped",
            loss_fn=stop_at_the_second_batch_of_epoch_1,
            checkpoint_minutes=0,
        )
    last = tmp_path / "stopped" / "weights" / "last.pt"
    state = load_checkpoint(last)
    assert state["epoch"] == 0 and state["partial"]["batch"] == 1  # epoch 1's first step is in it
    resumed = fit(tiny_dataset, tmp_path / "stopped", resume_from=last, checkpoint_minutes=0)
    a, b = load_checkpoint(straight["last"]), load_checkpoint(resumed["last"])
    for key in ("model", "ema"):
        for name, value in a[key].items():
            assert torch.equal(value, b[key][name]), f"{key}.{name} differs after a mid-epoch resume"
    assert b["partial"] is None
    assert [r["box"] for r in a["history"]] == pytest.approx([r["box"] for r in b["history"]])


def test_resume_with_other_settings_is_refused(straight_run, tmp_path):
    tiny_dataset, result = straight_run
    with pytest.raises(ValueError, match="lr0: checkpoint 0.01, configured 0.02"):
        fit(tiny_dataset, tmp_path / "run", resume_from=result["last"], lr0=0.02)
    # The number of loader workers does not change the samples, so it may differ; nor does the layout.
    assert fit(tiny_dataset, tmp_path / "run", resume_from=result["last"], workers=1)["history"]
    assert fit(tiny_dataset, tmp_path / "run2", resume_from=result["last"], channels_last=False)["history"]


def test_channels_last_computes_the_gradients_nchw_does(straight_run):
    """The trainer's default layout (`channels_last=True`, as in the straight run) changes only the order
    of the sums: in float32 one batch's loss and every gradient agree with NCHW's to 1e-3 of the tensor's
    largest (measured: 7e-5). Whole trainings drift further apart, as any reordering of sums makes them."""
    _, straight = straight_run
    state = load_checkpoint(straight["last"])
    assert state["settings"]["channels_last"] is True
    assert state["model"]["stem.conv.weight"].is_contiguous(memory_format=torch.channels_last)
    torch.manual_seed(0)
    nchw = tiny_model().train()
    nhwc = copy.deepcopy(nchw).to(memory_format=torch.channels_last)
    assert nhwc.stem.conv.weight.is_contiguous(memory_format=torch.channels_last)
    loss_fn = loss_for(nchw, SIZE)
    images = torch.rand(4, 3, SIZE, SIZE)
    targets = torch.tensor([[i, i % 3, 0.5, 0.5, 0.2, 0.2] for i in range(4)])
    losses = []
    for model, x in ((nchw, images), (nhwc, images.contiguous(memory_format=torch.channels_last))):
        loss, _ = loss_fn([p.float() for p in model(x)], targets)
        loss.backward()
        losses.append(loss.item())
    assert losses[0] == pytest.approx(losses[1], rel=1e-5)
    for (name, a), b in zip(nchw.named_parameters(), nhwc.parameters(), strict=True):
        assert (a.grad - b.grad).abs().max() <= 1e-3 * a.grad.abs().max() + 1e-12, name


def test_checkpoint_of_another_architecture_is_refused(straight_run, tmp_path):
    _, result = straight_run
    other = tiny_model(gam_position="after_sppf").arch
    with pytest.raises(ValueError, match="gam_position: checkpoint None, configured 'after_sppf'"):
        load_checkpoint(result["last"], arch=other)
    with pytest.raises(ValueError, match="not a spacetrack detector checkpoint"):
        torch.save({"state_dict": {}}, tmp_path / "foreign.pt")
        load_checkpoint(tmp_path / "foreign.pt")


def test_nan_loss_stops_and_keeps_the_last_good_checkpoint(tiny_dataset, tmp_path):
    model = tiny_model()
    real = loss_for(model, SIZE)
    calls = {"n": 0}

    def poisoned(raw, targets):
        calls["n"] += 1
        loss, parts = real(raw, targets)
        # Training batches of epoch 0 (2 per epoch) and its validation pass are fine; epoch 1 is not.
        return (loss * float("nan"), parts) if calls["n"] > 3 else (loss, parts)

    with pytest.raises(FloatingPointError, match=r"epoch 1 batch 0; stopped, .*last.pt \(epoch 0\) is kept"):
        fit(tiny_dataset, tmp_path / "run", loss_fn=poisoned)
    assert load_checkpoint(tmp_path / "run" / "weights" / "last.pt")["epoch"] == 0


def test_planned_epochs_fit_the_time_left():
    # 12 of 30 minutes spent on 2 epochs of 5 minutes (and 2 of setup): 18 left hold 3 more epochs
    assert planned_epochs(done=2, configured=16, elapsed_s=720, epoch_s=300, budget_s=1800) == 5
    # never more than configured, never fewer than done (an epoch longer than the whole budget)
    assert planned_epochs(done=2, configured=4, elapsed_s=60, epoch_s=10, budget_s=1800) == 4
    assert planned_epochs(done=1, configured=16, elapsed_s=2400, epoch_s=2400, budget_s=1800) == 1
    # a part of an epoch left is not an epoch
    assert planned_epochs(done=1, configured=16, elapsed_s=600, epoch_s=600, budget_s=1199) == 1


class EpochClock:
    """A clock that reads `minutes` minutes per epoch begun: each `set_epoch` of the training set is an
    epoch taking exactly that long, whatever the machine."""

    def __init__(self, train_set, minutes: float) -> None:
        self.now, self.minutes = 0.0, minutes
        begin = train_set.set_epoch

        def set_epoch(epoch: int) -> None:
            self.now += 60 * self.minutes
            begin(epoch)

        train_set.set_epoch = set_epoch

    def __call__(self) -> float:
        return self.now


def budgeted_fit(root, out_dir, *, minutes_per_epoch, resume_from=None, **overrides):
    torch.manual_seed(0)
    model = tiny_model()
    train, val = datasets(root)
    trainer = Trainer(**{**SETTINGS, "epochs": 3, **overrides})
    trainer.clock = EpochClock(train, minutes_per_epoch)
    result = trainer.fit(model=model, loss_fn=loss_for(model, SIZE), train_set=train, val_set=val,
                         out_dir=out_dir, resume_from=resume_from)  # fmt: skip
    return result, trainer


def test_a_time_budget_plans_the_epochs_that_fit_and_decays_the_rate_over_them(
    straight_run, tmp_path, capsys
):
    tiny_dataset, _ = straight_run
    # 10-minute epochs, 25 minutes: after the first epoch 15 minutes are left, one more epoch fits
    result, trainer = budgeted_fit(tiny_dataset, tmp_path / "run", minutes_per_epoch=10, max_minutes=25)
    assert result["planned_epochs"] == 2
    assert [r["epoch"] for r in result["history"]] == [0, 1]
    assert "so 2 of the 3 epochs fit" in capsys.readouterr().out
    # the second epoch's rate is the last of a 2-epoch schedule, not the middle of a 3-epoch one
    expected = trainer.lr0 * lr_factor(1, epochs=2, lrf=trainer.lrf, schedule=trainer.schedule)
    assert result["history"][1]["lr"] == pytest.approx(expected)
    assert expected != pytest.approx(trainer.lr0 * lr_factor(1, epochs=3, lrf=trainer.lrf, schedule="linear"))
    state = load_checkpoint(result["last"])
    assert state["planned_epochs"] == 2 and state["elapsed_s"] == pytest.approx(1200)
    # the plan is done: resume=auto finds nothing left to train in the folder
    settings = {**trainer.settings}
    assert unfinished_checkpoint([tmp_path], arch=tiny_model().arch, settings=settings) is None

    # Resumed without the budget, the run goes on to every configured epoch.
    resumed, _ = budgeted_fit(tiny_dataset, tmp_path / "run", minutes_per_epoch=10, max_minutes=None,
                              resume_from=result["last"])  # fmt: skip
    assert resumed["planned_epochs"] == 3
    assert [r["epoch"] for r in resumed["history"]] == [0, 1, 2]


def test_a_budget_that_holds_every_epoch_changes_nothing(straight_run, tmp_path):
    tiny_dataset, straight = straight_run
    result, _ = budgeted_fit(tiny_dataset, tmp_path / "run", minutes_per_epoch=1, max_minutes=30, epochs=2)
    a, b = load_checkpoint(straight["last"]), load_checkpoint(result["last"])
    assert b["planned_epochs"] == 2
    for name, value in a["model"].items():
        assert torch.equal(value, b["model"][name]), f"model.{name} differs under a budget that holds"


def test_a_budget_that_is_not_a_positive_number_is_refused():
    with pytest.raises(
        ValueError, match="train.trainer.max_minutes must be a positive number of minutes or null, got 0"
    ):
        Trainer(**{**SETTINGS, "max_minutes": 0})
