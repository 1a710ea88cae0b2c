import pytest
import torch

from spacetrack.models.yolo import YOLOv5, count_parameters


@pytest.mark.parametrize(("num_classes", "expected"), [(80, 7_235_389), (1, 7_022_326)])
def test_yolov5s_has_the_reference_parameter_count(num_classes, expected):
    assert count_parameters(YOLOv5(num_classes=num_classes)) == expected


def test_strides_and_output_shapes():
    model = YOLOv5(num_classes=3).eval()
    assert model.stride.tolist() == [8.0, 16.0, 32.0]
    x = torch.rand(2, 3, 320, 256)
    raw = model(x)
    assert [tuple(p.shape) for p in raw] == [(2, 3, 40, 32, 8), (2, 3, 20, 16, 8), (2, 3, 10, 8, 8)]
    decoded = model.predict(x)
    assert decoded.shape == (2, 3 * (40 * 32 + 20 * 16 + 10 * 8), 8)
    assert torch.all((decoded[..., 4:] >= 0) & (decoded[..., 4:] <= 1))


def test_decode_places_a_zero_logit_box_at_the_cell_centre_with_the_anchor_size():
    model = YOLOv5(num_classes=1).eval()
    raw = [torch.zeros(1, 3, 4, 4, 6), torch.zeros(1, 3, 2, 2, 6), torch.zeros(1, 3, 1, 1, 6)]
    decoded = model.detect.decode(raw)
    # sigmoid(0) = 0.5: xy = (0.5*2 - 0.5 + cell) * stride, wh = (0.5*2)^2 * anchor.
    assert decoded[0, 0, :4].tolist() == [4.0, 4.0, 10.0, 13.0]
    last = decoded[0, -1, :4].tolist()
    assert last == [16.0, 16.0, 373.0, 326.0]


def test_objectness_bias_prior():
    model = YOLOv5(num_classes=1)
    bias = model.detect.m[0].bias.view(3, -1)[:, 4]
    # About 8 objects per 640x640 image at stride 8: log(8 / 80^2), plus the small default conv init.
    assert torch.allclose(bias, torch.full_like(bias, -6.685), atol=0.2)


@pytest.mark.parametrize("position", ["before_sppf", "after_sppf"])
def test_gam_is_inserted_where_configured(position):
    plain = count_parameters(YOLOv5(num_classes=1))
    model = YOLOv5(num_classes=1, gam_position=position)
    gams = [n for n, m in model.named_modules() if type(m).__name__ == "GAM"]
    assert len(gams) == 1
    assert count_parameters(model) > plain
    assert model(torch.rand(1, 3, 64, 64))[2].shape == (1, 3, 2, 2, 6)


def test_unknown_gam_position_is_refused():
    with pytest.raises(ValueError, match="neck"):
        YOLOv5(num_classes=1, gam_position="neck")
