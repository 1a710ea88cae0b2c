"""ONNX Runtime backend: the same detections and features as torch, exports cached by content."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from omegaconf import open_dict

from spacetrack.config import compose_config
from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.models.yolo import YOLOv5
from spacetrack.onnx_backend import DETECTOR_BACKENDS, OrtSession, check_backend, onnx_session
from spacetrack.pipeline import YoloDetector
from spacetrack.pipeline.build import build_stream, cache_key, resolve_weights
from spacetrack.reid import Cropper, Encoder, ReidNet
from spacetrack.reid.weights import save_weights

pytestmark = pytest.mark.usefixtures("one_torch_thread")
SMALL_NET = {"input_height": 32, "input_width": 16, "feature_dim": 8}


@pytest.fixture(params=[False, True], ids=["three_levels", "p2"])
def tiny_yolo(request, tmp_path, one_torch_thread):
    """A random-init YOLOv5 at 1/8 width in a checkpoint: real layers, fast export; with and without the
    stride-4 level."""
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3, width_multiple=0.125, p2=request.param)
    weights = tmp_path / "best.pt"
    save_checkpoint(weights, {"arch": model.arch, "ema": model.state_dict()})
    return weights


@pytest.fixture
def onnx_dir(tmp_path):
    return tmp_path / "onnx"


def detector(weights, onnx_dir, backend):
    return YoloDetector(
        weights=weights,
        image_size=64,
        conf_threshold=0.0,
        max_det=50,
        device="cpu",
        backend=backend,
        threads=1,
        onnx_dir=onnx_dir,
    )


def test_detector_onnxruntime_matches_torch(tiny_yolo, onnx_dir):
    torch_det, ort_det = (detector(tiny_yolo, onnx_dir, b) for b in ("torch", "onnxruntime"))
    rgb = np.random.default_rng(0).integers(0, 255, (60, 130, 3), dtype=np.uint8)
    boxed = np.random.default_rng(1).integers(0, 255, (64, 64, 3), dtype=np.uint8)
    raw_torch, raw_ort = torch_det.predict(boxed), ort_det.predict(boxed)
    assert raw_ort.shape == raw_torch.shape and raw_ort.dtype == torch.float32
    # boxes in pixels (up to ~70), scores in [0, 1]: float32 rounding of two graph implementations
    torch.testing.assert_close(raw_ort, raw_torch, rtol=1e-4, atol=1e-4)
    # Past the network both backends share letterbox, NMS and scaling. Random weights score dozens of
    # boxes alike, so NMS ties may break either way: the rows are checked, not matched one to one.
    boxes = ort_det(rgb, 1)
    assert boxes.shape[1] == 6 and 0 < len(boxes) <= 50 and (boxes[:, :2] >= 0).all()
    assert (boxes[:, 0] + boxes[:, 2] <= 130 + 1e-6).all() and (boxes[:, 1] + boxes[:, 3] <= 60 + 1e-6).all()
    assert "backend=onnxruntime" in ort_det.identity and "backend=torch" in torch_det.identity
    assert ort_det.session(64, 64).path.parent == onnx_dir and torch_det.backend == "torch"


def test_native_resolution_exports_one_graph_per_frame_size(tiny_yolo, onnx_dir):
    native = YoloDetector(weights=tiny_yolo, conf_threshold=0.0, device="cpu", backend="onnxruntime",
                          threads=1, onnx_dir=onnx_dir)  # fmt: skip
    by_torch = YoloDetector(weights=tiny_yolo, conf_threshold=0.0, device="cpu", backend="torch")
    rgb = np.random.default_rng(0).integers(0, 255, (60, 130, 3), dtype=np.uint8)
    boxes = native(rgb, 1)
    assert sorted(p.name.split("-")[0] for p in onnx_dir.glob("*.onnx")) == ["yolo64x160"]
    assert "size=native" in native.identity
    reference = by_torch(rgb, 1)
    # random weights score many boxes alike, so ties may come out in either order: the scores agree in
    # order, and each of the five best boxes is one of the torch backend's
    assert np.allclose(boxes[:20, 4], reference[:20, 4], atol=1e-4)
    assert all(np.isclose(reference[:, :6], row, atol=1e-2).all(axis=1).any() for row in boxes[:5, :6])


def test_encoder_onnxruntime_matches_torch_at_any_batch(tmp_path):
    torch.manual_seed(0)
    net = ReidNet(**SMALL_NET)
    cropper = Cropper(height=32, width=16)
    by_torch = Encoder(net, cropper, device="cpu", batch_size=4)
    by_ort = Encoder(net, cropper, device="cpu", batch_size=4, backend="onnxruntime", onnx_dir=tmp_path)
    frame = np.random.default_rng(0).integers(0, 255, (80, 120, 3), dtype=np.uint8)
    for boxes in (
        [[5, 5, 20, 30]],
        np.random.default_rng(1).uniform([0, 0, 5, 5], [100, 60, 40, 40], (7, 4)),
    ):
        np.testing.assert_allclose(by_ort(frame, boxes), by_torch(frame, boxes), rtol=1e-4, atol=1e-5)
    assert by_ort(frame, np.zeros((0, 4))).shape == (0, 8)


def test_export_is_cached_and_follows_the_weights(tmp_path):
    torch.manual_seed(0)
    net = torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.ReLU())
    x = np.random.default_rng(0).random((1, 3, 8, 8), dtype=np.float32)
    first = onnx_session(net, (1, 3, 8, 8), cache_dir=tmp_path)
    stamp = first.path.stat().st_mtime_ns
    again = onnx_session(net, (1, 3, 8, 8), cache_dir=tmp_path)
    assert again.path == first.path and again.path.stat().st_mtime_ns == stamp  # not exported again
    with torch.no_grad():
        net[0].weight.add_(1.0)
        changed = onnx_session(net, (1, 3, 8, 8), cache_dir=tmp_path)
        np.testing.assert_allclose(changed(x)[0], net(torch.from_numpy(x)).numpy(), rtol=1e-5, atol=1e-5)
    assert changed.path != first.path
    assert onnx_session(net, (1, 3, 16, 16), cache_dir=tmp_path).path not in (first.path, changed.path)


@pytest.mark.parametrize("damage", [b"", b"not a protobuf" * 10, "truncated"])
def test_a_damaged_cached_file_is_exported_again(tmp_path, caplog, damage):
    net = torch.nn.Conv2d(3, 2, 1)
    path = onnx_session(net, (1, 3, 4, 4), cache_dir=tmp_path).path
    good = path.read_bytes()
    path.write_bytes(good[: len(good) // 2] if damage == "truncated" else damage)
    with caplog.at_level(logging.WARNING, logger="spacetrack.onnx_backend"):
        session = onnx_session(net, (1, 3, 4, 4), cache_dir=tmp_path)
    assert session.path == path and path.read_bytes() == good
    assert "exporting it again" in caplog.text
    assert session(np.ones((1, 3, 4, 4), np.float32))[0].shape == (1, 2, 4, 4)


def test_settings_are_checked(tmp_path):
    with pytest.raises(ValueError, match="backend must be one of"):
        check_backend("tensorrt")
    path = onnx_session(torch.nn.Conv2d(3, 2, 1), (1, 3, 4, 4), cache_dir=tmp_path).path
    with pytest.raises(ValueError, match="threads must be >= 0"):
        OrtSession(path, threads=-1)
    with pytest.raises(ValueError, match="'cpu' or 'cuda'"):
        OrtSession(path, device="mps")
    # the reid encoder has no INT8 or bfloat16 backend: only the detector's choices hold them
    with pytest.raises(ValueError, match="backend must be one of"):
        check_backend("onnxruntime_int8")
    assert check_backend("onnxruntime_int8", "cpu", DETECTOR_BACKENDS) == "onnxruntime_int8"


def test_sessions_do_not_spin_between_calls_unless_asked(tmp_path):
    """Spinning intra-op threads would hold both cores after a call, slowing the stage that runs next."""
    path = onnx_session(torch.nn.Conv2d(3, 2, 1), (1, 3, 4, 4), cache_dir=tmp_path).path

    def spinning(session):
        return session.session.get_session_options().get_session_config_entry(
            "session.intra_op.allow_spinning"
        )

    assert spinning(OrtSession(path, threads=2)) == "0"
    assert spinning(OrtSession(path, threads=2, spinning=True)) == "1"


def test_missing_onnxruntime_names_the_install(monkeypatch, tmp_path):
    monkeypatch.setitem(__import__("sys").modules, "onnxruntime", None)
    with pytest.raises(ImportError, match="make install"):
        onnx_session(torch.nn.Conv2d(3, 2, 1), (1, 3, 4, 4), cache_dir=tmp_path)
    assert not list(tmp_path.iterdir())  # nothing exported for a session that cannot run


def test_track_config_builds_onnxruntime_networks_and_keys_the_cache_on_the_backend(
    tiny_yolo, onnx_dir, tmp_path
):
    reid = tmp_path / "reid.pt"
    save_weights(reid, ReidNet(**SMALL_NET), net_kwargs=SMALL_NET, crop_kwargs={"height": 32, "width": 16})

    def config(*overrides):
        base = [f"detector.weights={tiny_yolo}", f"reid.weights={reid}", "logger=none"]
        return compose_config("track", base + list(overrides))

    source = SimpleNamespace(name="seq", description="seq", num_frames=10, files=())

    def key(cfg):
        return cache_key(cfg, resolve_weights(cfg), source)

    torch_only = ("detector.backend=torch", "reid.backend=torch")
    plain = key(config(*torch_only))
    assert key(config(*torch_only, "detector.threads=2", f"detector.onnx_dir={tmp_path}")) == plain
    # settings that change the speed only keep the cache; motion settings do not
    assert key(config(*torch_only, "motion.parallel=true", "overlap_reid=false")) == plain
    assert key(config(*torch_only, "motion.min_support=4")).motion != plain.motion
    # features of low-scoring boxes are left out: another threshold is another cache
    assert key(config(*torch_only, "reid_min_score=0")).reid == plain.reid.split(" ")[0]
    without_backend = config(*torch_only)
    with open_dict(without_backend):
        del without_backend.detector.backend  # a config from before the key: its caches stay valid
    assert key(without_backend) == plain
    cfg = config("detector.backend=onnxruntime", "reid.backend=onnxruntime", "detector.image_size=64",
                 f"detector.onnx_dir={onnx_dir}", f"reid.onnx_dir={onnx_dir}", "detector.device=cpu",
                 "reid.device=cpu")  # fmt: skip
    by_ort = key(cfg)
    assert by_ort.detector != plain.detector
    assert by_ort.reid == plain.reid.replace(" min_score", " onnxruntime min_score")
    # "auto" is what runs: onnxruntime on the CPU, so it shares that cache; torch on CUDA
    auto_cpu = config("detector.image_size=64", "detector.device=cpu", "reid.device=cpu")
    assert auto_cpu.detector.backend == auto_cpu.reid.backend == "auto"
    assert key(auto_cpu) == by_ort
    assert check_backend("auto", "cuda") == "torch" and check_backend("auto", "cpu") == "onnxruntime"
    stream = build_stream(cfg, resolve_weights(cfg))
    assert stream.detector.session(64, 64).path.parent == stream.encoder.session.path.parent == onnx_dir
