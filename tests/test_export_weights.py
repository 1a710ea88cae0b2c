"""fp16 export keeps what the loaders need and gives the same model, up to half precision; the ONNX
export gives the same outputs as torch."""

from __future__ import annotations

import numpy as np
import onnxruntime as ort
import pytest
import torch

from spacetrack.engine.checkpoint import load_detector, save_checkpoint
from spacetrack.export_weights import export_detector, export_reid, main
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


@pytest.mark.usefixtures("one_torch_thread")
def test_onnx_export_gives_the_torch_outputs(tmp_path, capsys):
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3, width_multiple=0.125).eval()
    save_checkpoint(tmp_path / "best.pt", {"arch": model.arch, "ema": model.state_dict()})
    small = {"input_height": 32, "input_width": 16, "feature_dim": 8}
    net = ReidNet(**small).eval()
    save_weights(tmp_path / "reid.pt", net, net_kwargs=small, crop_kwargs={"height": 32, "width": 16})
    main(["--onnx", "--image-size", "96x64", "--detector", str(tmp_path / "best.pt")]
         + ["--reid", str(tmp_path / "reid.pt"), "--out", str(tmp_path), "--suffix", "t"])  # fmt: skip
    image, crops = torch.rand(1, 3, 64, 96), torch.rand(3, 3, 32, 16)  # the re-ID graph takes any batch
    for name, network, x in (("detector_yolov5s_t_96x64", model.predict, image), ("reid_t", net, crops)):
        session = ort.InferenceSession(str(tmp_path / f"{name}.onnx"), providers=["CPUExecutionProvider"])
        (out,) = session.run(None, {"input": x.numpy()})
        with torch.no_grad():
            np.testing.assert_allclose(out, network(x).numpy(), rtol=1e-4, atol=1e-4)
    with pytest.raises(SystemExit):
        main(
            ["--onnx", "--image-size", "100", "--detector", str(tmp_path / "best.pt"), "--out", str(tmp_path)]
        )
    assert "--image-size sides must be positive multiples of 32, got '100'" in capsys.readouterr().err
