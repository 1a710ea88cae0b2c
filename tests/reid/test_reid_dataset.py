"""Identities and crops from the dataset layout; seeded augmentation."""

from __future__ import annotations

import numpy as np
import pytest

from spacetrack.reid.crops import Cropper
from spacetrack.reid.dataset import CropDataset, collect_crops, cut_crops, jitter_augment

SEQS = ["seq_000_nominal", "seq_001_dim"]


def test_identities_are_sequence_target_pairs_and_filters_apply(tiny_dataset) -> None:
    table = collect_crops(tiny_dataset, SEQS, min_visibility=0.3, min_box_size=4, include_static=False)
    assert table.names == [(s, t) for s in SEQS for t in (1, 2, 3)]
    # 3 targets x 6 frames, less target 2 hidden in frame 3 and target 3 at 20 % in frame 5, per sequence
    assert len(table) == 2 * (18 - 2)
    hidden = (table.frame == 3) & np.isin(table.identity, [1, 4])
    assert not hidden.any()
    with_static = collect_crops(tiny_dataset, SEQS, min_visibility=0.0, min_box_size=4, include_static=True)
    assert ("seq_000_nominal", 1000) in with_static.names and len(with_static.names) == 8
    # visibility 0 rows (conf 0) never give a crop, even at min_visibility 0
    assert len(with_static) == 2 * (24 - 1)
    strided = collect_crops(
        tiny_dataset, SEQS, min_visibility=0.3, min_box_size=4, include_static=False, frame_stride=2
    )
    assert set(strided.frame.tolist()) == {1, 3, 5}
    big = collect_crops(tiny_dataset, SEQS, min_visibility=0.3, min_box_size=12, include_static=False)
    assert {n[1] for n in big.names} == {1, 3}  # target 2 is 10 px wide


def test_no_usable_crop_is_an_error(tiny_dataset) -> None:
    with pytest.raises(ValueError, match="no usable crops"):
        collect_crops(tiny_dataset, SEQS, min_visibility=0.3, min_box_size=500, include_static=False)
    with pytest.raises(FileNotFoundError, match="seq_999"):
        collect_crops(tiny_dataset, ["seq_999"], min_visibility=0.3, min_box_size=4, include_static=False)


def test_cut_crops_show_the_target(tiny_dataset) -> None:
    table = collect_crops(tiny_dataset, SEQS[:1], min_visibility=0.3, min_box_size=4, include_static=False)
    crops = cut_crops(tiny_dataset, table, Cropper(mode="stretch", margin=0.0), scale=1.25)
    assert crops.shape == (len(table), 160, 80, 3) and crops.dtype == np.uint8
    centre = crops[:, 60:100, 30:50].reshape(len(table), -1, 3).mean(axis=1)
    dominant = centre.argmax(axis=1)
    np.testing.assert_array_equal(dominant, table.identity)  # red, green, blue targets


def test_augmentation_is_seeded_by_epoch_and_index(tiny_dataset) -> None:
    table = collect_crops(tiny_dataset, SEQS[:1], min_visibility=0.3, min_box_size=4, include_static=False)
    crops = cut_crops(tiny_dataset, table, Cropper(), scale=1.25)
    augment = jitter_augment(
        height=128, width=64, jitter_scale=0.1, jitter_shift=0.05, brightness=0.3, flip=0.5, blur=0.2
    )
    data = CropDataset(crops, table.identity, height=128, width=64, augment=augment, seed=1)
    first, label = data[2]
    assert first.shape == (3, 128, 64) and label == table.identity[2]
    assert (data[2][0] == first).all()
    data.epoch = 1
    assert not (data[2][0] == first).all()
    plain = CropDataset(crops, table.identity, height=128, width=64)
    np.testing.assert_array_equal(
        plain[0][0].permute(1, 2, 0).mul(255).round().byte().numpy(), crops[0, 16:144, 8:72]
    )


def test_each_crop_carries_its_objects_class_from_moving_and_parked_rows(tmp_path):
    gt = tmp_path / "seq_a" / "gt"
    gt.mkdir(parents=True)
    (gt / "gt.txt").write_text("1,1,10,10,5,5,1,2,1.0\n2,1,11,10,5,5,1,2,1.0\n1,2,50,50,8,8,1,0,0.5\n")
    (gt / "static.txt").write_text("1,1000,200,200,9,9,1,1,1.0\n")
    (tmp_path / "seq_b" / "gt").mkdir(parents=True)
    (tmp_path / "seq_b" / "gt" / "gt.txt").write_text("1,1,0,0,4,4,1,1,1.0\n")
    table = collect_crops(
        tmp_path, ["seq_a", "seq_b"], min_visibility=0.0, min_box_size=0.0, include_static=True
    )
    classes = {table.names[i]: int(c) for i, c in zip(table.identity, table.object_class, strict=True)}
    assert classes == {("seq_a", 1): 2, ("seq_a", 2): 0, ("seq_a", 1000): 1, ("seq_b", 1): 1}
