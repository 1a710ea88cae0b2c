"""fp16 export keeps what the loaders need and gives the same model, up to half precision."""

from __future__ import annotations

import torch

from spacetrack.engine.checkpoint import load_detector, save_checkpoint
from spacetrack.export_weights import export_detector, export_reid
from spacetrack.models.yolo import YOLOv5
from spacetrack.reid.network import ReidNet
from spacetrack.reid.weights import load_weights, save_weights


def _tensors(out) -> list[torch.Tensor]:
    if torch.is_tensor(out):
        return [out]
    return [t for item in out for t in _tensors(item)]


def test_detector_export_is_half_precision_and_loads(tmp_path):
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3).eval()
    save_checkpoint(
        tmp_path / "best.pt", {"arch": model.arch, "ema": model.state_dict(), "optimizer": {"lr": 1}}
    )
    out = export_detector(tmp_path / "best.pt", tmp_path / "small.pt")
    state = torch.load(out, weights_only=True)
    assert "optimizer" not in state
    assert all(v.dtype == torch.float16 for v in state["ema"].values() if v.is_floating_point())
    loaded = load_detector(out)
    x = torch.rand(1, 3, 64, 64)
    with torch.no_grad():
        a, b = model(x), loaded(x)
    pairs = list(zip(_tensors(a), _tensors(b), strict=True))
    assert pairs and all(torch.allclose(x, y, rtol=1e-2, atol=1e-2) for x, y in pairs)


def test_reid_export_is_half_precision_and_loads(tmp_path):
    torch.manual_seed(0)
    net = ReidNet().eval()
    save_weights(tmp_path / "reid.pt", net, net_kwargs={}, crop_kwargs={})
    out = export_reid(tmp_path / "reid.pt", tmp_path / "small.pt")
    tensors = torch.load(out, weights_only=True)["model"].values()
    assert all(v.dtype == torch.float16 for v in tensors if v.is_floating_point())
    loaded, _ = load_weights(out)
    x = torch.rand(2, 3, 128, 64)
    with torch.no_grad():
        assert torch.allclose(net(x), loaded(x), atol=1e-2)
