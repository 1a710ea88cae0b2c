import pytest
import torch

from spacetrack.models.gam import GAM, ChannelAttention, SpatialAttention, channel_shuffle


@pytest.mark.parametrize("groups", [1, 4])
def test_gam_keeps_shape_and_gates_between_zero_and_one(groups):
    gam = GAM(channels=32, reduction=4, groups=groups).eval()
    x = torch.rand(2, 32, 5, 7) + 0.1
    y = gam(x)
    assert y.shape == x.shape
    # Two sigmoid gates: every output is a positive fraction of its input.
    ratio = y / x
    assert torch.all((ratio > 0) & (ratio < 1))


def test_channel_attention_mixes_channels_per_pixel_only():
    cam = ChannelAttention(channels=8, reduction=4).eval()
    x = torch.rand(1, 8, 6, 6)
    y = cam(x)
    x2 = x.clone()
    x2[:, :, 0, 0] += 1.0
    y2 = cam(x2)
    changed = (y2 - y).abs().sum(dim=1)[0] > 0
    assert changed[0, 0] and changed.sum() == 1


def test_spatial_attention_reaches_seven_by_seven_neighbours_twice():
    sam = SpatialAttention(channels=8, reduction=4).eval()
    x = torch.rand(1, 8, 15, 15)
    x2 = x.clone()
    x2[:, :, 7, 7] += 1.0
    changed = (sam(x2) - sam(x)).abs().sum(dim=1)[0] > 0
    # Two 7x7 convolutions: the receptive field is 13x13 around the changed pixel, and no further.
    assert changed.sum() > 49
    outside = changed.clone()
    outside[1:14, 1:14] = False
    assert not outside.any()


def test_grouped_variant_is_lighter_and_rejects_bad_groups():
    full = sum(p.numel() for p in GAM(channels=64).parameters())
    light = sum(p.numel() for p in GAM(channels=64, groups=4).parameters())
    assert light < full / 2
    with pytest.raises(ValueError, match="groups=3"):
        GAM(channels=64, groups=3)


def test_channel_shuffle_interleaves_groups():
    x = torch.arange(6.0).view(1, 6, 1, 1)
    assert channel_shuffle(x, 2).flatten().tolist() == [0.0, 3.0, 1.0, 4.0, 2.0, 5.0]
