import numpy as np
import pytest

from spacetrack.data.yolo_dataset import (
    YoloDataset,
    build_augmentation,
    collate,
    image_source,
    letterbox,
    letterbox_labels,
    read_labels,
)

AUGMENT = {
    "hue": 5,
    "saturation": 20,
    "value": 20,
    "fliplr": 0.5,
    "flipud": 0.5,
    "scale": 0.2,
    "translate": 0.1,
}


def test_letterbox_keeps_boxes_on_their_pixels():
    image = np.zeros((48, 64, 3), dtype=np.uint8)
    image[12:20, 20:30] = 255
    labels = np.array([[1, 25 / 64, 16 / 48, 10 / 64, 8 / 48]], dtype=np.float32)
    boxed, scale, pad = letterbox(image, 32)
    assert boxed.shape == (32, 32, 3) and scale == 0.5 and pad == (0, 4)
    out = letterbox_labels(labels, image.shape[:2], scale, pad, 32)
    cx, cy, w, h = out[0, 1:] * 32
    assert (cx, cy, w, h) == pytest.approx((12.5, 12.0, 5.0, 4.0))
    assert boxed[4, 0, 0] == 0 and boxed[0, 0, 0] == 114  # picture, then grey padding rows


def test_dataset_batches_and_seeded_augmentation(tiny_dataset):
    augment = build_augmentation(**AUGMENT)
    ds = YoloDataset(root=tiny_dataset, sequences=["seq_000_nominal", "seq_001_nominal"], num_classes=3,
                     image_size=64, frame_stride=2, augment=augment, seed=1)  # fmt: skip
    assert len(ds) == 4
    first = ds[1]
    again = ds[1]
    assert np.array_equal(first[0], again[0]) and np.array_equal(first[1], again[1])
    ds.set_epoch(1)
    draws = [ds[i][0] for i in range(4)]
    ds.set_epoch(0)
    assert any(not np.array_equal(a, ds[i][0]) for i, a in enumerate(draws))
    images, targets = collate([ds[0], ds[1]])
    assert images.shape == (2, 3, 64, 64) and str(images.dtype) == "torch.uint8"
    assert targets.shape[1] == 6 and set(targets[:, 0].tolist()) <= {0.0, 1.0}


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("0 0.5 0.5 0.1\n", "line 1: expected 5 values"),
        ("0 0.5 0.5 0.1 0.1\n7 0.5 0.5 0.1 0.1\n", "line 2: class 7 is outside 0..2"),
        ("0 0.5 1.5 0.1 0.1\n", "not normalised"),
        ("0 0.5 abc 0.1 0.1\n", "non-numeric"),
    ],
)
def test_malformed_labels_are_refused_with_file_and_line(tmp_path, text, message):
    path = tmp_path / "000001.txt"
    path.write_text(text)
    with pytest.raises(ValueError, match=message) as err:
        read_labels(path, num_classes=3)
    assert str(path) in str(err.value)


def test_missing_label_file_and_empty_image_are_errors(tiny_dataset):
    seq = tiny_dataset / "seq_000_nominal"
    (seq / "labels" / "000002.txt").unlink()
    with pytest.raises(FileNotFoundError, match="000002.txt"):
        YoloDataset(root=tiny_dataset, sequences=["seq_000_nominal"], num_classes=3, image_size=64)
    (seq / "labels" / "000002.txt").write_text("")
    (seq / "img" / "000003.jpg").write_bytes(b"")
    ds = YoloDataset(root=tiny_dataset, sequences=["seq_000_nominal"], num_classes=3, image_size=64)
    with pytest.raises(ValueError, match="000003.jpg"):
        ds[2]


def test_pre_enhanced_folder_is_preferred(tiny_dataset):
    assert image_source(tiny_dataset, ["seq_000_nominal"], "none") == ("img", False)
    assert image_source(tiny_dataset, ["seq_000_nominal"], "dwt_hsv") == ("img", True)
    (tiny_dataset / "seq_000_nominal" / "img_dwt_hsv").mkdir()
    assert image_source(tiny_dataset, ["seq_000_nominal"], "dwt_hsv") == ("img_dwt_hsv", False)
