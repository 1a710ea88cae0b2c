"""Re-ID weights files: the network's state dict with the constructor keywords of the network and the
cropper that made its training crops, so an encoder built from the file crops exactly as training did."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from spacetrack.io import atomic_path, load_torch_file
from spacetrack.reid.crops import Cropper
from spacetrack.reid.network import ReidNet

FORMAT = "spacetrack-reid-1"


def save_weights(
    path: str | Path, net: ReidNet, *, net_kwargs: dict[str, Any], crop_kwargs: dict[str, Any]
) -> None:
    """Write the weights of `net` (built with `net_kwargs`) and the crop settings to `path`, atomically."""
    state = {"format": FORMAT, "net": dict(net_kwargs), "crop": dict(crop_kwargs), "model": net.state_dict()}
    with atomic_path(path) as tmp:
        torch.save(state, tmp)


def load_weights(path: str | Path) -> tuple[ReidNet, Cropper]:
    """The network (eval mode, on the CPU) and cropper stored at `path`; a file of another format or
    whose tensors do not fit the stored architecture is a ValueError naming the file and the tensors."""
    state = load_torch_file(path, "weights file")
    if not isinstance(state, dict) or state.get("format") != FORMAT:
        raise ValueError(f"{path} is not a spacetrack re-ID weights file (expected format {FORMAT!r})")
    net = ReidNet(**state["net"])
    expected = net.state_dict()
    found = state["model"]
    problems = [f"missing {k}" for k in expected if k not in found]
    problems += [f"unexpected {k}" for k in found if k not in expected]
    problems += [
        f"{k}: file {tuple(found[k].shape)}, network {tuple(v.shape)}"
        for k, v in expected.items()
        if k in found and found[k].shape != v.shape
    ]
    if problems:
        raise ValueError(f"{path}: weights do not fit ReidNet({state['net']}): " + "; ".join(problems[:5]))
    net.load_state_dict(found)
    return net.eval(), Cropper(**state["crop"])
