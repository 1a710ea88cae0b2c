"""Conv+BN folding for inference: the same outputs, one layer fewer per block, the trained model untouched."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from spacetrack.models.yolo import YOLOv5, fuse_for_inference, fused_conv

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def randomise_batch_norms(model: nn.Module, seed: int = 0) -> None:
    """Running statistics and affine terms away from their 0/1 defaults, so a wrong fold shows."""
    gen = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.running_mean.copy_(torch.randn(m.num_features, generator=gen) * 0.5)
                m.running_var.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
                m.weight.copy_(torch.rand(m.num_features, generator=gen) + 0.5)
                m.bias.copy_(torch.randn(m.num_features, generator=gen) * 0.2)


@pytest.mark.parametrize("bias", [False, True])
def test_fused_conv_equals_conv_then_batch_norm(bias):
    torch.manual_seed(0)
    conv, bn = nn.Conv2d(4, 6, 3, stride=2, padding=1, bias=bias), nn.BatchNorm2d(6, eps=1e-3)
    randomise_batch_norms(bn)
    bn.eval()
    x = torch.randn(2, 4, 9, 11)
    fused = fused_conv(conv, bn)
    torch.testing.assert_close(fused(x), bn(conv(x)), rtol=1e-5, atol=1e-5)
    assert fused.bias is not None and not fused.weight.requires_grad


@pytest.mark.parametrize(
    "gam", [{}, {"gam_position": "after_sppf"}, {"gam_position": "before_sppf", "gam_groups": 2}]
)
def test_fused_network_predicts_as_the_trained_one(gam):
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3, width_multiple=0.125, **gam)
    randomise_batch_norms(model)
    model.train()  # the trained model may be in either mode: the copy is in eval mode whatever it is
    before = {k: v.clone() for k, v in model.state_dict().items()}
    fused = fuse_for_inference(model)
    model.eval()
    x = torch.rand(1, 3, 64, 96)
    with torch.no_grad():
        expected = model.predict(x)
        got = fused.predict(x)
        cl = fused.to(memory_format=torch.channels_last).predict(
            x.contiguous(memory_format=torch.channels_last)
        )
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-3)
    torch.testing.assert_close(cl, expected, rtol=1e-4, atol=1e-3)
    assert not any(isinstance(m, nn.BatchNorm2d) for m in fused.modules())
    # the trained model keeps its layers and values (its checkpoints and training are unchanged)
    assert sum(isinstance(m, nn.BatchNorm2d) for m in model.modules()) > 20
    assert all(torch.equal(before[k], v) for k, v in model.state_dict().items())
