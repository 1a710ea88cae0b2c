"""The detector's faster backends: fused torch, bfloat16 where the CPU has it, INT8 by ONNX Runtime."""

from __future__ import annotations

import logging
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from spacetrack.config import compose_config
from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.engine.precision import native_bfloat16
from spacetrack.models.yolo import YOLOv5
from spacetrack.pipeline import YoloDetector
from spacetrack.pipeline.build import cache_key, resolve_weights
from spacetrack.quantize import METADATA_KEY, Calibration, stored_description
from spacetrack.reid import ReidNet
from spacetrack.reid.weights import save_weights

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def checkpoint(path, seed=0, settings=True):
    """A random-init YOLOv5 at 1/8 width; with `settings`, trained (it says) on dataset `tiny`, fold 3."""
    torch.manual_seed(seed)
    model = YOLOv5(num_classes=3, width_multiple=0.125)
    state = {"arch": model.arch, "ema": model.state_dict()}
    if settings:
        state["settings"] = {"data": {"name": "tiny"}, "fold": 3,
                             "enhance": {"_target_": "spacetrack.enhance.NoEnhancement"}}  # fmt: skip
    save_checkpoint(path, state)
    return path


@pytest.fixture
def weights(tmp_path):
    return checkpoint(tmp_path / "best.pt")


def int8(weights, data, onnx_dir, **kwargs):
    settings = {"calibration_frames": 6, **kwargs}
    return YoloDetector(weights=weights, conf_threshold=0.0, device="cpu", backend="onnxruntime_int8",
                        threads=1, onnx_dir=onnx_dir, calibration_data=data, **settings)  # fmt: skip


def frame(seed=0):
    """A dark sky with a few bright boxes, the size of the tiny dataset's frames (64x48)."""
    rng = np.random.default_rng(seed)
    image = rng.integers(0, 30, (48, 64, 3), dtype=np.uint8)
    for x, y in rng.integers(4, 40, (3, 2)):
        image[y : y + 6, x : x + 9] = 220
    return image


def test_torch_backend_is_the_fused_network_and_predicts_as_the_checkpoint(weights):
    det = YoloDetector(weights=weights, conf_threshold=0.0, device="cpu", backend="torch")
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in det.network.modules())
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in det.model.modules())
    boxed = np.ascontiguousarray(np.pad(frame(), ((0, 16), (0, 0), (0, 0))))  # native: padded to 64x64
    x = torch.from_numpy(boxed).permute(2, 0, 1)[None].float() / 255
    with torch.no_grad():
        expected = det.model.predict(x)
    got = det.predict(boxed)
    assert not got.requires_grad
    torch.testing.assert_close(got, expected, rtol=1e-4, atol=1e-3)


@pytest.mark.skipif(not native_bfloat16(), reason="this CPU has no native bfloat16 (AVX512-BF16 or AMX)")
def test_bfloat16_detections_match_float32(tmp_path):
    from spacetrack.config import REPO_ROOT
    from spacetrack.data.layout import read_rgb

    shipped = REPO_ROOT / "weights" / "detector_yolov5s_fold3.pt"
    sample = REPO_ROOT / "data" / "space_default" / "seq_000_nominal" / "img" / "000050.jpg"
    if not (shipped.is_file() and sample.is_file()):
        pytest.skip("needs the shipped fold-3 weights and data/space_default (make data)")
    rgb = read_rgb(sample)
    fp32 = YoloDetector(weights=shipped, device="cpu", backend="torch")(rgb, 1)
    bf16 = YoloDetector(weights=shipped, device="cpu", backend="torch_bf16")(rgb, 1)
    fp32, bf16 = fp32[fp32[:, 4] >= 0.25], bf16[bf16[:, 4] >= 0.25]
    assert len(fp32) > 0 and len(bf16) == len(fp32)
    order = lambda d: d[np.lexsort((d[:, 1], d[:, 0]))]  # noqa: E731
    # bfloat16 keeps 8 mantissa bits: the network's boxes move by a fraction of a pixel (measured on this
    # frame with native bfloat16: 0.54 px at most, on a 152-px side; boxes are decoded in float32)
    np.testing.assert_allclose(order(bf16)[:, :4], order(fp32)[:, :4], atol=1.0)
    np.testing.assert_allclose(order(bf16)[:, 4], order(fp32)[:, 4], atol=0.01)


@pytest.mark.skipif(native_bfloat16(), reason="this CPU has native bfloat16")
def test_bfloat16_is_refused_where_the_cpu_would_only_emulate_it(weights):
    with pytest.raises(ValueError, match="torch_bf16 needs native bfloat16"):
        YoloDetector(weights=weights, device="cpu", backend="torch_bf16")


def test_int8_detector_keeps_the_float_boxes_and_is_cached(weights, tiny_dataset, tmp_path):
    onnx_dir = tmp_path / "onnx"
    quantised = int8(weights, tiny_dataset, onnx_dir)
    floating = YoloDetector(weights=weights, conf_threshold=0.0, device="cpu", backend="onnxruntime",
                            threads=1, onnx_dir=onnx_dir)  # fmt: skip
    boxed = np.ascontiguousarray(np.pad(frame(), ((0, 16), (0, 0), (0, 0))))
    got, expected = quantised.predict(boxed)[0], floating.predict(boxed)[0]
    # box decoding stays float: centres and sizes within a few pixels of 64, scores within a few hundredths
    assert got.shape == expected.shape and not torch.equal(got, expected)
    assert (got[:, :4] - expected[:, :4]).abs().max() < 4.0
    assert (got[:, 4:] - expected[:, 4:]).abs().max() < 0.05
    path = quantised.session(64, 64).path
    assert path.parent == onnx_dir and "-int8-" in path.name
    desc = stored_description(path)
    assert desc["calibration"]["frames"] == 6 and desc["data"]["held_out_fold"] == 3
    # calibrated on the eight training folds' frames only, never the checkpoint's validation fold
    assert "seq_003_nominal" not in desc["data"]["sequences"] and len(desc["data"]["sequences"]) == 8
    stamp = path.stat().st_mtime_ns
    again = int8(weights, tiny_dataset, onnx_dir)
    assert again.session(64, 64).path == path and path.stat().st_mtime_ns == stamp  # reused
    other = int8(weights, tiny_dataset, onnx_dir, calibration_frames=5)
    assert other.session(64, 64).path != path
    assert "backend=onnxruntime_int8" in quantised.identity and "calibration=" in quantised.identity
    boxes = quantised(frame(), 1)
    assert boxes.shape[1] == 6 and (boxes[:, 0] + boxes[:, 2] <= 64 + 1e-6).all()


def test_a_quantised_file_from_other_weights_is_made_again(weights, tiny_dataset, tmp_path, caplog):
    onnx_dir = tmp_path / "onnx"
    mine = int8(weights, tiny_dataset, onnx_dir).session(64, 64).path
    other_weights = checkpoint(tmp_path / "other.pt", seed=1)
    theirs = int8(other_weights, tiny_dataset, onnx_dir).session(64, 64).path
    assert theirs != mine
    made_for_me = stored_description(mine)
    mine.write_bytes(theirs.read_bytes())  # a file under my name, quantised from the other weights
    with caplog.at_level(logging.WARNING, logger="spacetrack.quantize"):
        int8(weights, tiny_dataset, onnx_dir).session(64, 64)
    assert "quantising again" in caplog.text
    assert stored_description(mine) == made_for_me
    mine.write_bytes(mine.read_bytes()[:1000])  # truncated
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="spacetrack.quantize"):
        session = int8(weights, tiny_dataset, onnx_dir).session(64, 64)
    assert "unreadable" in caplog.text and stored_description(mine) == made_for_me
    assert session(np.zeros((1, 3, 64, 64), np.float32))[0].shape[-1] == 8


def test_int8_settings_and_missing_pieces_are_named(weights, tiny_dataset, tmp_path, monkeypatch):
    onnx_dir = tmp_path / "onnx"
    with pytest.raises(ValueError, match="calibration method must be one of"):
        int8(weights, tiny_dataset, onnx_dir, calibration_method="kl")
    with pytest.raises(ValueError, match="positive integer, got 0"):
        Calibration(frames=0)
    missing = tmp_path / "no_such_dataset"
    with pytest.raises(FileNotFoundError, match="no_such_dataset"):
        int8(weights, missing, onnx_dir).session(64, 64)
    bare = checkpoint(tmp_path / "bare.pt", settings=False)
    with pytest.raises(ValueError, match=r"bare\.pt records no training dataset"):
        int8(bare, None, onnx_dir).session(64, 64)
    with pytest.raises(ValueError, match="backend must be one of"):
        YoloDetector(weights=weights, device="cpu", backend="int8")
    monkeypatch.setitem(sys.modules, "onnxruntime", None)
    with pytest.raises(ImportError, match="onnxruntime and onnx packages"):
        int8(weights, tiny_dataset, onnx_dir).session(64, 64)


def test_the_cache_key_tells_int8_from_float_and_its_calibration(weights, tmp_path):
    reid, small = tmp_path / "reid.pt", {"input_height": 32, "input_width": 16, "feature_dim": 8}
    save_weights(reid, ReidNet(**small), net_kwargs=small, crop_kwargs={"height": 32, "width": 16})

    def key(*overrides):
        cfg = compose_config("track", [f"detector.weights={weights}", f"reid.weights={reid}", "logger=none",
                                       "detector.device=cpu", *overrides])  # fmt: skip
        return cache_key(
            cfg, resolve_weights(cfg), SimpleNamespace(name="seq", description="seq", num_frames=10, files=())
        ).detector

    auto, ort = key(), key("detector.backend=onnxruntime")
    quantised = key("detector.backend=onnxruntime_int8")
    assert auto == ort  # `auto` still runs float32 ONNX Runtime on a CPU: its caches stay valid
    assert quantised not in (ort, key("detector.backend=torch"))
    assert key("detector.backend=onnxruntime_int8", "+detector.calibration_frames=32") != quantised
    assert METADATA_KEY.startswith("spacetrack")


def test_test_time_augmentation_runs_the_same_views_on_torch_and_onnx_runtime(weights, tmp_path):
    rgb = np.random.default_rng(5).integers(0, 255, (160, 192, 3), dtype=np.uint8)
    common = {"weights": weights, "conf_threshold": 0.0, "device": "cpu", "max_det": 10_000}
    plain = YoloDetector(**common, backend="torch")
    torch_tta = YoloDetector(**common, backend="torch", tta=True)
    onnx_tta = YoloDetector(**common, backend="onnxruntime", tta=True, threads=1, onnx_dir=tmp_path / "onnx")
    one, three = plain.predict(rgb)[0], torch_tta.predict(rgb)[0]
    # 160x192 at 0.83 is 128x160 (the nearest multiples of 32), at 0.67 96x128: anchors of all three views
    sizes = ((160, 192), (128, 160), (96, 128))
    per_view = [sum(3 * (h // s) * (w // s) for s in (8, 16, 32)) for h, w in sizes]
    assert len(one) == per_view[0] and len(three) == sum(per_view)
    torch.testing.assert_close(three[: len(one)], one)  # the first view is the frame as it is
    from_onnx = onnx_tta.predict(rgb)[0]
    assert from_onnx.shape == three.shape and (from_onnx - three).abs().max() < 1e-3
    assert sorted(p.name.split("-")[0] for p in (tmp_path / "onnx").glob("*.onnx")) == [
        "yolo128x160", "yolo160x192", "yolo96x128"]  # fmt: skip
    assert " tta" in torch_tta.identity and "tta" not in plain.identity
    boxes = onnx_tta(rgb, 1)
    assert boxes.shape[1] == 6 and (boxes[:, 0] + boxes[:, 2] <= 192 + 1e-4).all()


def test_test_time_augmentation_takes_its_own_views(weights):
    rgb = np.random.default_rng(6).integers(0, 255, (160, 192, 3), dtype=np.uint8)
    common = {
        "weights": weights,
        "conf_threshold": 0.0,
        "device": "cpu",
        "max_det": 10_000,
        "backend": "torch",
    }
    plain = YoloDetector(**common)
    enlarged = YoloDetector(**common, tta=[[1.0, False], [1.5, False]])
    one, two = plain.predict(rgb)[0], enlarged.predict(rgb)[0]
    # 160x192 enlarged by half is 240x288, 256x288 at multiples of 32: the frame's anchors, then the view's
    per_view = [sum(3 * (h // s) * (w // s) for s in (8, 16, 32)) for h, w in ((160, 192), (256, 288))]
    assert len(one) == per_view[0] and len(two) == sum(per_view)
    torch.testing.assert_close(two[: len(one)], one)
    # boxes of the enlarged view come back in the frame's pixels
    assert two[len(one) :, 0].max() <= 192 * 1.2
    assert enlarged.identity.endswith(" tta=1,1.5") and " tta" not in plain.identity
    assert YoloDetector(**common, tta=True).identity.endswith(" tta")
    assert YoloDetector(**common, tta=[[1.0, False], [1.5, True, 32]]).identity.endswith(" tta=1,1.5m<32")


@pytest.mark.parametrize(
    "tta", [[], [[0.0, False]], [[1.0, "yes"]], [1.0], "views", [[1.5, False, 0]], [[1.5, False, 32, 1]]]
)
def test_test_time_augmentation_refuses_bad_views(weights, tta):
    with pytest.raises(ValueError, match="tta"):
        YoloDetector(weights=weights, device="cpu", backend="torch", tta=tta)


def test_a_view_with_a_max_side_keeps_only_its_small_boxes():
    from spacetrack.engine.inference import augmented_predictions

    def predict(view):
        # two boxes in the view's pixels: 20x20 and 60x60, objectness 0.9
        return torch.tensor([[[50.0, 50.0, 20.0, 20.0, 0.9, 1.0], [80.0, 80.0, 60.0, 60.0, 0.9, 1.0]]])

    x = torch.zeros(1, 3, 64, 64)
    plain = augmented_predictions(predict, x, [(1.0, False)])
    enlarged = augmented_predictions(predict, x, [(1.0, False), (2.0, False, 20)])
    torch.testing.assert_close(enlarged[:, :2], plain)
    # the enlarged view's boxes come back at half their size (10 and 30 px): only the 10 px one is kept
    torch.testing.assert_close(enlarged[0, 2:, 2:4], torch.tensor([[10.0, 10.0], [30.0, 30.0]]))
    assert enlarged[0, 2:, 4].tolist() == [pytest.approx(0.9), 0.0]
