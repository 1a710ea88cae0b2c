"""The Table 1 network: layer shapes, unit-norm output, input checks, the final-ELU option."""

from __future__ import annotations

import pytest
import torch

from spacetrack.reid.network import ReidNet


def test_table1_shapes_and_unit_features() -> None:
    torch.manual_seed(0)
    net = ReidNet().eval()
    x = torch.rand(3, 3, 128, 64)
    h = net.stem(x)
    assert h.shape == (3, 32, 64, 32)  # after conv 1, conv 2 and the stride-2 pool
    shapes = []
    for block in net.blocks[:6]:
        h = block(h)
        shapes.append(tuple(h.shape[1:]))
    assert shapes == [(32, 64, 32), (32, 64, 32), (64, 32, 16), (64, 32, 16), (128, 16, 8), (128, 16, 8)]
    features = net(x)
    assert features.shape == (3, 128)
    torch.testing.assert_close(features.norm(dim=1), torch.ones(3))


def test_wrong_input_size_is_refused() -> None:
    with pytest.raises(ValueError, match=r"\(N, 3, 128, 64\)"):
        ReidNet().eval()(torch.rand(1, 3, 64, 64))
    with pytest.raises(ValueError, match="multiples of 8"):
        ReidNet(input_height=100)


def test_final_elu_keeps_the_original_positive_bias() -> None:
    torch.manual_seed(0)
    original = ReidNet(final_elu=True).eval()
    ours = ReidNet(final_elu=False).eval()
    x = torch.rand(8, 3, 128, 64)
    with torch.no_grad():
        assert isinstance(original.head[-1], torch.nn.ELU)
        assert not isinstance(ours.head[-1], torch.nn.ELU)
        # ELU bounds every component below by -1 before normalisation, BN alone does not
        assert (original.head(original.blocks(original.stem(x))) >= -1).all()
