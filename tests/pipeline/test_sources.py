"""Frame sources and the bad input they refuse: changing sizes, unreadable or truncated videos, no camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from spacetrack.pipeline.sources import SourceError, limit, open_source
from spacetrack.viz.video import VideoWriter


def _write_frames(folder, sizes):
    folder.mkdir()
    for i, (w, h) in enumerate(sizes, start=1):
        cv2.imwrite(str(folder / f"{i:06d}.png"), np.full((h, w, 3), 20 * i, np.uint8))


def test_folder_of_frames_in_order_and_limited(tmp_path):
    _write_frames(tmp_path / "clip", [(32, 24)] * 4)
    source = open_source(tmp_path / "clip")
    assert source.num_frames == 4 and source.name == "clip"
    frames = list(limit(source, 3))
    assert len(frames) == 3 and frames[1].shape == (24, 32, 3) and frames[1][0, 0, 0] == 40


def test_frames_of_changing_size_name_the_frame(tmp_path):
    _write_frames(tmp_path / "clip", [(32, 24), (32, 24), (40, 24)])
    with pytest.raises(SourceError, match=r"frame 3 is 40x24 but the first frame was 32x24"):
        list(open_source(tmp_path / "clip"))


def test_video_file_unreadable_and_truncated(tmp_path):
    path = tmp_path / "clip.mp4"
    with VideoWriter(path, fps=10, size=(64, 48)) as video:
        for i in range(20):
            video.write(np.full((48, 64, 3), 10 * i, np.uint8))
    source = open_source(path)
    assert source.num_frames == 20 and len(list(source)) == 20
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video at all" * 100)
    with pytest.raises(SourceError, match="broken.mp4"):
        list(open_source(broken))
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    with pytest.raises(SourceError, match="cut.mp4"):
        list(open_source(cut))


def test_missing_camera_and_unknown_source(tmp_path):
    with pytest.raises(SourceError, match="camera 57 is not available"):
        open_source(57)
    with pytest.raises(FileNotFoundError, match="neither a camera index"):
        open_source(tmp_path / "nothing.here")
