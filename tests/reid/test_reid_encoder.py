"""The encoder the tracker uses: shapes, unit norm, determinism, batching, bad boxes, weights files."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from spacetrack.reid import Cropper, Encoder, ReidNet
from spacetrack.reid.crops import frame_tensor
from spacetrack.reid.weights import save_weights

NET = {"input_height": 128, "input_width": 64, "feature_dim": 128, "dropout": 0.3, "final_elu": False}
CROP = {"height": 128, "width": 64, "mode": "contain", "margin": 0.1, "min_size": 1.0}


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    torch.manual_seed(0)
    path = tmp_path_factory.mktemp("weights") / "reid.pt"
    save_weights(path, ReidNet(**NET), net_kwargs=NET, crop_kwargs=CROP)
    return path


@pytest.fixture(scope="module")
def frame() -> np.ndarray:
    rng = np.random.default_rng(0)
    return rng.integers(0, 255, (96, 128, 3), dtype=np.uint8)


def test_features_are_unit_float32_and_deterministic(weights, frame) -> None:
    encoder = Encoder.from_weights(weights, device="cpu")
    boxes = np.array(
        [[10, 10, 30, 20], [60, 40, 12, 30], [-20, -20, 40, 40], [500, 500, 10, 10], [5, 5, 0, 0]]
    )
    features = encoder(frame, boxes)
    assert features.shape == (5, 128) and features.dtype == np.float32
    inside = [0, 1, 2, 4]  # box 3 lies wholly outside the frame: a zero row, no appearance
    np.testing.assert_allclose(np.linalg.norm(features[inside], axis=1), 1.0, rtol=1e-5)
    assert not features[3].any()
    np.testing.assert_array_equal(encoder(frame, boxes), features)
    # a box's feature does not depend on the other boxes of its batch
    single = Encoder.from_weights(weights, device="cpu", batch_size=1)(frame, boxes)
    np.testing.assert_allclose(single, features, atol=1e-5)
    assert not np.allclose(features[0], features[1])
    # the encoder converts only the sampled part of the frame: the same features as from the whole frame
    whole = encoder.encode_crops(encoder.cropper(frame_tensor(frame), boxes[inside]))
    np.testing.assert_allclose(features[inside], whole, atol=1e-5)
    np.testing.assert_allclose(encoder(frame, boxes[1:2]), features[1:2], atol=1e-5)  # a part away from 0, 0


def test_empty_box_list(weights, frame) -> None:
    encoder = Encoder.from_weights(weights, device="cpu")
    assert encoder(frame, np.zeros((0, 4))).shape == (0, 128)
    assert encoder(frame, []).shape == (0, 128)


def test_bad_input_is_refused(weights, frame) -> None:
    encoder = Encoder.from_weights(weights, device="cpu")
    with pytest.raises(ValueError, match="box 0 is not finite"):
        encoder(frame, [[np.inf, 0, 4, 4]])
    with pytest.raises(ValueError, match="RGB uint8"):
        encoder(frame[..., 0], [[0, 0, 4, 4]])


def test_wrong_weights_name_the_file_and_tensors(tmp_path) -> None:
    bad = tmp_path / "bad.pt"
    state = ReidNet(**NET).state_dict()
    state["head.2.weight"] = torch.zeros(64, 16384)
    torch.save({"format": "spacetrack-reid-1", "net": NET, "crop": CROP, "model": state}, bad)
    with pytest.raises(
        ValueError, match=r"bad\.pt.*head\.2\.weight: file \(64, 16384\), network \(128, 16384\)"
    ):
        Encoder.from_weights(bad)
    other = tmp_path / "detector.pt"
    torch.save({"model": state}, other)
    with pytest.raises(ValueError, match="not a spacetrack re-ID weights file"):
        Encoder.from_weights(other)
    junk = tmp_path / "junk.pt"
    junk.write_text("not torch")
    with pytest.raises(ValueError, match="junk.pt is not a readable weights file"):
        Encoder.from_weights(junk)
    with pytest.raises(FileNotFoundError, match="missing.pt"):
        Encoder.from_weights(tmp_path / "missing.pt")


def test_cropper_must_fit_the_network() -> None:
    with pytest.raises(ValueError, match="64x32 crops"):
        Encoder(ReidNet(**NET), Cropper(height=64, width=32), device="cpu")
