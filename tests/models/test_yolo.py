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


def test_the_stride_4_level_comes_last_and_leaves_the_three_level_path_as_it_is():
    torch.manual_seed(0)
    plain = YOLOv5(num_classes=3).eval()
    torch.manual_seed(1)
    p2 = YOLOv5(num_classes=3, p2=True).eval()
    assert p2.stride.tolist() == [8.0, 16.0, 32.0, 4.0]
    assert (
        p2.arch["p2"] is True and "p2" not in plain.arch
    )  # older files keep the arch they were written with
    assert p2.detect.anchors[3].tolist() == [[5.0, 6.5], [8.0, 15.0], [16.5, 11.5]]
    # Every tensor of the three-level network has its name and shape in the four-level one.
    shapes = {k: v.shape for k, v in p2.state_dict().items()}
    own = {k: v for k, v in plain.state_dict().items() if k not in ("detect.anchors", "detect.stride")}
    assert all(shapes[k] == v.shape for k, v in own.items())
    p2.load_state_dict(own, strict=False)
    x = torch.rand(1, 3, 96, 128)
    with torch.no_grad():
        three, four = plain(x), p2(x)
    assert [tuple(p.shape) for p in four] == [
        (1, 3, 12, 16, 8), (1, 3, 6, 8, 8), (1, 3, 3, 4, 8), (1, 3, 24, 32, 8)
    ]  # fmt: skip
    assert all(torch.equal(a, b) for a, b in zip(three, four[:3], strict=True))
    assert p2.predict(x).shape == (1, 3 * (12 * 16 + 6 * 8 + 3 * 4 + 24 * 32), 8)


def test_anchor_levels_must_match_the_head():
    with pytest.raises(ValueError, match="3 anchor levels for a 4-level head"):
        YOLOv5(num_classes=1, p2=True, anchors=((10, 13, 16, 30, 33, 23),) * 3)


@pytest.mark.parametrize("stages", [-1, 6, 2.5, True, "5"])
def test_freeze_outside_the_backbone_stages_is_refused(stages):
    with pytest.raises(ValueError, match=rf"freeze: expected 0-5 backbone stages .*got {stages!r}"):
        YOLOv5(num_classes=3, width_multiple=0.125).freeze_backbone(stages)


@pytest.mark.parametrize("gam_position", [None, "after_sppf"])
def test_frozen_backbone_blocks_keep_their_weights_and_backpropagation_stops_at_them(gam_position):
    from spacetrack.engine.optim import build_optimizer

    torch.manual_seed(0)
    model = YOLOv5(num_classes=3, width_multiple=0.125, gam_position=gam_position)
    assert model.freeze_backbone(0) == [] and all(p.requires_grad for p in model.parameters())
    assert model.freeze_backbone(2) == ["stem", "stage2"]
    assert model.freeze_backbone(5) == ["stem", "stage2", "stage3", "stage4", "stage5"]
    frozen = {n for n, _ in model.named_parameters() if n.split(".")[0].startswith(("stem", "stage"))}
    assert frozen and {n for n, p in model.named_parameters() if not p.requires_grad} == frozen
    if gam_position:  # the GAM block sits in stage5: frozen with it
        gam = {n for n, _ in model.named_parameters() if n.startswith("stage5.4.")}
        assert gam and gam <= frozen
    before = {n: p.detach().clone() for n, p in model.named_parameters()}
    optimizer = build_optimizer(model, lr0=0.1, momentum=0.9, weight_decay=5e-4)
    model.train()
    loss = sum(level.square().mean() for level in model(torch.rand(2, 3, 64, 64)))
    loss.backward()
    assert all(p.grad is None for n, p in model.named_parameters() if n in frozen)
    optimizer.step()
    for name, p in model.named_parameters():
        moved = not torch.equal(p.detach(), before[name])
        assert moved == (name not in frozen), name
