"""The detection cache on its own: detections and motion blobs as two parts, each valid with its sidecar."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from spacetrack.motion.blobs import Blob
from spacetrack.pipeline.cache import CacheKey, CacheMismatchError, DetectionCache, blob_table, blobs_by_frame

KEY = CacheKey(detector="det 1234", reid="reid 99", enhance="e1", motion="m1", source="seq (3 frames)")


def _rows() -> np.ndarray:
    rows = np.full((4, 12), -1.0)
    rows[:, 0] = [1, 1, 2, 3]
    rows[:, 2:7] = [[10, 10, 5, 5, 0.9], [40, 40, 6, 6, 0.8], [11, 10, 5, 5, 0.9], [12, 10, 5, 5, 0.7]]
    rows[:, 10:] = 0.5
    return rows


BLOBS = [[Blob((12.5, 12.0), (10, 10, 5, 5), 16.0)], [], [Blob((14.0, 12.5), (12, 10, 5, 5), 16.0)]]


def test_blob_table_round_trip_keeps_every_frame():
    table = blob_table(BLOBS)
    assert table.shape == (2, 8) and table[:, 0].tolist() == [1, 3]
    assert blobs_by_frame(table, 3) == BLOBS
    assert blob_table([[], []]).shape == (0, 8)


def test_detections_and_blobs_load_as_saved(tmp_path):
    cache = DetectionCache(tmp_path)
    assert cache.load("seq", KEY) is None
    cache.save("seq", KEY, _rows(), np.array([0, 1, 0, 0]), num_frames=3)
    cached = cache.load("seq", KEY)
    assert np.array_equal(cached.rows, _rows()) and cached.classes.tolist() == [0, 1, 0, 0]
    assert cached.num_frames == 3 and cached.blobs is None  # no blobs yet: the motion stage must run
    cache.save_blobs("seq", KEY, BLOBS)
    assert cache.load("seq", KEY).blobs == BLOBS
    # other motion settings: the detections still serve, their blobs are missing; the first stay
    other = replace(KEY, motion="m2")
    assert cache.load("seq", other).blobs is None
    cache.save_blobs("seq", other, [None, None, None])  # a stream without a motion stage
    assert cache.load("seq", other).blobs == [None, None, None]
    assert cache.load("seq", KEY).blobs == BLOBS
    # other networks: nothing serves
    assert cache.load("seq", replace(KEY, detector="det 5678")) is None


def test_damaged_or_old_parts_are_rebuilt_or_refused_by_name(tmp_path, caplog):
    cache = DetectionCache(tmp_path)
    cache.save("seq", KEY, _rows(), np.zeros(4, int), num_frames=3)
    cache.save_blobs("seq", KEY, BLOBS)
    blobs_path = next(tmp_path.glob("seq.blobs-*.npy"))
    table = np.load(blobs_path)
    table[1, 0] = 7  # a frame the sequence does not have
    np.save(blobs_path, table)
    assert cache.load("seq", KEY).blobs is None
    with pytest.raises(
        CacheMismatchError, match=r"seq\.blobs-m1\.json is stale: blob frames 1-7 outside 1-3"
    ):
        DetectionCache(tmp_path, rebuild=False).load("seq", KEY)
    meta = tmp_path / "seq.json"
    old = json.loads(meta.read_text()) | {"format": 1}
    meta.write_text(json.dumps(old))
    with caplog.at_level("INFO"):
        assert cache.load("seq", KEY) is None
    assert "format 1, this version reads 2" in caplog.text
    with pytest.raises(CacheMismatchError, match=r"seq\.json is stale: format 1"):
        DetectionCache(tmp_path, rebuild=False).load("seq", KEY)
