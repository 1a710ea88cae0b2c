"""Decoded-frame cache and native-resolution training crops, on the smoke dataset (320x240 frames)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from spacetrack.data.crops import CropDataset, check_crop_size, pick_target, window_labels
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import frame_paths, load_manifest, read_rgb
from spacetrack.data.yolo_dataset import YoloDataset, frame_samples, read_labels


@pytest.fixture
def store(smoke_dataset, tmp_path):
    return FrameStore(root=smoke_dataset, cache_dir=tmp_path / "frames", progress=False)


def sequences(root, scenario=None):
    return [s["name"] for s in load_manifest(root)["sequences"] if scenario in (None, s["scenario"])]


def test_store_holds_the_decoded_frames_and_rebuilds_a_stale_cache(smoke_dataset, store):
    seq = sequences(smoke_dataset)[0]
    paths = frame_paths(smoke_dataset, seq)
    frames = store.frames(seq)
    assert frames.shape == (len(paths), 240, 320, 3) and frames.dtype == np.uint8
    assert np.array_equal(frames[5], read_rgb(paths[5]))
    meta = store.folder / f"{seq}.json"
    stale = json.loads(meta.read_text()) | {"content_hash": "sha256:another-dataset"}
    meta.write_text(json.dumps(stale))
    again = FrameStore(root=smoke_dataset, cache_dir=store.folder.parent, progress=False)
    assert np.array_equal(again.frames(seq)[5], read_rgb(paths[5]))
    assert json.loads(meta.read_text())["content_hash"] == load_manifest(smoke_dataset)["content_hash"]


def test_store_caches_enhanced_frames_apart(smoke_dataset, store):
    seq = sequences(smoke_dataset)[0]
    inverted = FrameStore(
        root=smoke_dataset,
        cache_dir=store.folder.parent,
        enhancer=lambda rgb: 255 - rgb,
        enhancer_name="invert",
        progress=False,
    )
    assert inverted.folder != store.folder
    assert np.array_equal(inverted.frames(seq)[0], 255 - store.frames(seq)[0])


def test_strided_store_holds_every_kth_frame_apart_and_refuses_the_others(smoke_dataset, store):
    seq = sequences(smoke_dataset)[0]
    paths = frame_paths(smoke_dataset, seq)
    every3 = FrameStore(root=smoke_dataset, cache_dir=store.folder.parent, frame_stride=3, progress=False)
    assert every3.folder != store.folder
    assert len(every3.frames(seq)) == len(paths[::3])
    assert np.array_equal(every3.frame(seq, 6), read_rgb(paths[6]))
    assert np.array_equal(every3.frame(seq, 6), store.frame(seq, 6))
    with pytest.raises(ValueError, match=f"frame 4 of {seq} is not cached.*frames 0, 3, 6, ... only"):
        every3.frame(seq, 4)
    # samples of a stride the store serves read the same pixels as from a whole store
    strided = YoloDataset(root=smoke_dataset, sequences=[seq], num_classes=3, store=every3, frame_stride=6)
    whole = YoloDataset(root=smoke_dataset, sequences=[seq], num_classes=3, store=store, frame_stride=6)
    assert np.array_equal(strided.image(2), whole.image(2))
    with pytest.raises(ValueError, match="frame_stride must be a whole number >= 1, got 0"):
        FrameStore(root=smoke_dataset, cache_dir=store.folder.parent, frame_stride=0)


def test_unreadable_frame_is_named_and_leaves_no_cache(smoke_dataset, tmp_path):
    seq = sequences(smoke_dataset)[0]
    copy = tmp_path / "copy"
    import shutil

    shutil.copytree(smoke_dataset, copy)
    frame_paths(copy, seq)[3].write_bytes(b"")
    broken = FrameStore(root=copy, cache_dir=tmp_path / "frames", progress=False)
    with pytest.raises(ValueError, match="000004.jpg: cannot read image"):
        broken.prepare([seq])
    assert not list((tmp_path / "frames").glob("**/*.npy"))


def test_native_frames_keep_their_resolution_and_labels(smoke_dataset, store):
    seq = sequences(smoke_dataset)[0]
    data = YoloDataset(root=smoke_dataset, sequences=[seq], num_classes=3, store=store, frame_stride=7)
    image, labels = data[1]
    assert image.shape == (256, 320, 3)  # 240 rows padded to a multiple of 32 at the bottom
    assert not image[240:].any()
    expected = read_labels(smoke_dataset / seq / "labels" / "000008.txt", 3)
    assert np.allclose(labels[:, [1, 3]], expected[:, [1, 3]])
    assert np.allclose(labels[:, [2, 4]], expected[:, [2, 4]] * 240 / 256)


def test_window_labels_clip_and_drop_boxes_at_the_edge():
    # 100x100 frame; boxes (pixels): one inside the window, one half out, one mostly out.
    boxes = np.array([[10, 10, 20, 20], [50, 10, 70, 30], [58, 40, 78, 60]], dtype=np.float32)
    labels = np.column_stack(
        ([0, 1, 2], (boxes[:, 0] + boxes[:, 2]) / 200, (boxes[:, 1] + boxes[:, 3]) / 200,
         (boxes[:, 2] - boxes[:, 0]) / 100, (boxes[:, 3] - boxes[:, 1]) / 100)
    ).astype(np.float32)  # fmt: skip
    out = window_labels(labels, (100, 100), 0, 0, 60, min_visibility=0.4)
    assert out[:, 0].tolist() == [0, 1]
    assert out[0, 1:] * 60 == pytest.approx([15, 15, 10, 10])
    assert out[1, 1:] * 60 == pytest.approx([55, 20, 10, 20])  # clipped to columns 50..60


def test_crops_are_native_pixels_around_targets_and_seeded(smoke_dataset, store):
    names = sequences(smoke_dataset)
    data = CropDataset(
        root=smoke_dataset, sequences=names, num_classes=3, store=store, crop_size=96, background=0.0, seed=4
    )
    samples = frame_samples(smoke_dataset, names, "img", 1, 3)
    labelled = [i for i, s in enumerate(samples) if len(s[3])]
    with_target = 0
    for i in labelled[:40]:
        image, labels = data[i]
        assert image.shape == (96, 96, 3)
        with_target += len(labels) > 0
        # no resizing: the window is a piece of the frame
        frame = store.frames(samples[i][0])[samples[i][1]]
        assert any(
            np.array_equal(image, frame[y : y + 96, x : x + 96])
            for y in range(frame.shape[0] - 95)
            for x in range(frame.shape[1] - 95)
            if frame[y, x, 0] == image[0, 0, 0]
        )
    assert with_target >= 0.9 * min(40, len(labelled))
    first = data[labelled[0]]
    assert np.array_equal(first[0], data[labelled[0]][0])
    data.set_epoch(1)
    assert any(not np.array_equal(first[0], data[i][0]) for i in labelled[:1])


@pytest.mark.parametrize(("small_bias", "ratio"), [(0.0, 1.0), (1.0, 5.0), (2.0, 25.0)])
def test_small_bias_centres_windows_on_small_targets_more_often(small_bias, ratio):
    # a 10x10 px and a 50x50 px target on a 100x100 frame: chosen 1:1, 5:1 and 25:1
    labels = np.array([[0, 0.2, 0.2, 0.1, 0.1], [1, 0.6, 0.6, 0.5, 0.5]], dtype=np.float32)
    rng = np.random.default_rng(0)
    picks = np.bincount([pick_target(labels, (100, 100), small_bias, rng) for _ in range(6000)], minlength=2)
    assert picks[0] / picks[1] == pytest.approx(ratio, rel=0.15)


def test_small_bias_out_of_range_is_refused(smoke_dataset, store):
    with pytest.raises(ValueError, match="small_bias must lie in"):
        CropDataset(root=smoke_dataset, sequences=sequences(smoke_dataset)[:1], num_classes=3, store=store,
                    crop_size=64, small_bias=-1.0)  # fmt: skip


def test_mosaic_tiles_four_windows(smoke_dataset, store):
    names = sequences(smoke_dataset)
    data = CropDataset(root=smoke_dataset, sequences=names, num_classes=3, store=store, crop_size=128,
                       mosaic=1.0, background=0.0)  # fmt: skip
    image, labels = data[10]
    assert image.shape == (128, 128, 3)
    assert len(labels) and (labels[:, 1:] >= 0).all() and (labels[:, 1:] <= 1).all()


@pytest.mark.parametrize(
    ("size", "message"), [(100, "multiple of 32"), (0, "multiple of 32"), (256, "larger than the 320x240")]
)
def test_bad_crop_size_is_refused(size, message):
    with pytest.raises(ValueError, match=message):
        check_crop_size(size, (240, 320, 3), "sequence s")


def test_a_dataset_without_labels_is_refused(smoke_dataset, tmp_path):
    import shutil

    copy = tmp_path / "unlabelled"
    shutil.copytree(smoke_dataset, copy)
    for label in copy.glob("*/labels/*.txt"):
        label.write_text("")
    empty = FrameStore(root=copy, cache_dir=tmp_path / "frames", progress=False)
    with pytest.raises(ValueError, match="no labelled target"):
        CropDataset(root=copy, sequences=sequences(copy)[:2], num_classes=3, store=empty, crop_size=64)
