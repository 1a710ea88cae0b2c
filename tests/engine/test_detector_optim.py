import pytest
import torch
from torch import nn

from spacetrack.config import compose_config
from spacetrack.engine.optim import ModelEMA, build_optimizer, lr_factor, set_learning_rates


def test_three_parameter_groups_and_decay_only_on_weights():
    model = nn.Sequential(nn.Conv2d(3, 4, 3, bias=False), nn.BatchNorm2d(4), nn.Conv2d(4, 2, 1))
    opt = build_optimizer(model, lr0=0.01, momentum=0.9, weight_decay=5e-4)
    bn, weights, biases = (g["params"] for g in opt.param_groups)
    assert [p.shape for p in bn] == [torch.Size([4])]
    assert [p.shape for p in weights] == [torch.Size([4, 3, 3, 3]), torch.Size([2, 4, 1, 1])]
    assert [p.shape for p in biases] == [torch.Size([4]), torch.Size([2])]
    assert [g["weight_decay"] for g in opt.param_groups] == [0, 5e-4, 0.0]
    assert all(g["nesterov"] for g in opt.param_groups)


def test_schedules_run_from_one_to_lrf():
    for schedule in ("linear", "cosine"):
        assert lr_factor(0, epochs=10, lrf=0.01, schedule=schedule) == pytest.approx(1.0)
        assert lr_factor(10, epochs=10, lrf=0.01, schedule=schedule) == pytest.approx(0.01)
    with pytest.raises(ValueError, match="'step'"):
        lr_factor(0, epochs=10, lrf=0.01, schedule="step")


def test_warmup_ramps_biases_down_and_weights_up():
    opt = build_optimizer(nn.Conv2d(1, 1, 1), lr0=0.01, momentum=0.9, weight_decay=0.0)
    kwargs = {"warmup_iterations": 10, "target_lr": 0.01, "momentum": 0.9, "warmup_momentum": 0.8}
    set_learning_rates(opt, iteration=0, warmup_bias_lr=0.1, **kwargs)
    assert [g["lr"] for g in opt.param_groups] == [0.0, 0.0, 0.1]
    set_learning_rates(opt, iteration=5, warmup_bias_lr=0.1, **kwargs)
    assert opt.param_groups[2]["lr"] == pytest.approx(0.055) and opt.param_groups[1]["lr"] == pytest.approx(
        0.005
    )
    set_learning_rates(opt, iteration=10, warmup_bias_lr=0.1, **kwargs)
    assert {g["lr"] for g in opt.param_groups} == {0.01} and {g["momentum"] for g in opt.param_groups} == {
        0.9
    }


def test_ema_follows_the_model_at_its_decay():
    model = nn.Linear(1, 1, bias=False)
    nn.init.zeros_(model.weight)
    ema = ModelEMA(model, decay=0.5, tau=1e-9)
    with torch.no_grad():
        model.weight.fill_(1.0)
    ema.update(model)
    ema.update(model)
    assert ema.module.weight.item() == pytest.approx(0.75)


def test_cpu_profile_ema_horizon_is_short_beside_its_run():
    # With the reference 0.9999 (a 10,000-step horizon) the EMA of a few-hundred-step run stays near
    # its first weights and validates as an untrained model.
    cfg = compose_config("train", ["logger=none"])
    train_frames = cfg.data.num_sequences * (1 - 1 / cfg.data.num_folds) * cfg.data.num_frames
    steps = cfg.train.trainer.epochs * train_frames / cfg.train.frame_stride / cfg.train.trainer.batch_size
    assert 1 / (1 - cfg.train.trainer.ema_decay) < steps / 4
