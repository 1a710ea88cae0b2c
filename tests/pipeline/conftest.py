"""Pipeline fixtures: random-init re-ID weights (real crops and features, no training)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from spacetrack.config import compose_config
from spacetrack.reid.weights import save_weights


@pytest.fixture(scope="session")
def random_reid(tmp_path_factory) -> Path:
    """Table 1 re-ID weights at random initialisation: real crops and features, no training."""
    cfg = compose_config("train_reid", ["logger=none"])
    torch.manual_seed(0)
    net = instantiate(cfg.model.net)
    path = tmp_path_factory.mktemp("reid") / "reid.pt"
    kwargs = {k: v for k, v in OmegaConf.to_container(cfg.model.net, resolve=True).items() if k != "_target_"}
    crop = {k: v for k, v in OmegaConf.to_container(cfg.model.crop, resolve=True).items() if k != "_target_"}
    save_weights(path, net, net_kwargs=kwargs, crop_kwargs=crop)
    return path
