"""MP4 clips: readable by OpenCV with the frames written, H.264, and nothing left behind on failure."""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from spacetrack.viz import VideoWriter, read_video_frames

W, H = 64, 48


def frames(n: int, h: int = H, w: int = W) -> list[np.ndarray]:
    """Flat grey frames getting brighter, plus a red square that moves right."""
    out = []
    for i in range(n):
        frame = np.full((h, w, 3), 20 + 15 * i, dtype=np.uint8)
        frame[10:26, 2 + 3 * i : 18 + 3 * i] = (255, 0, 0)
        out.append(frame)
    return out


def test_clip_reads_back_with_its_frame_count_size_and_content(tmp_path: Path) -> None:
    path = tmp_path / "clip.mp4"
    written = frames(12)
    with VideoWriter(path, fps=10, size=(W, H)) as video:
        for frame in written:
            video.write(frame)
    assert video.frames_written == 12

    read = list(read_video_frames(path))
    assert len(read) == 12
    assert all(frame.shape == (H, W, 3) and frame.dtype == np.uint8 for frame in read)
    for i, (ours, theirs) in enumerate(zip(written, read, strict=True)):
        # Lossy codec: compare away from the square's edges, in RGB order.
        assert abs(int(theirs[40, 40, 1]) - int(ours[40, 40, 1])) <= 6, f"frame {i} background"
        red = theirs[18, 10 + 3 * i]
        assert red[0] > 200 and red[2] < 60, f"frame {i} square should be red, got {red}"

    capture = cv2.VideoCapture(str(path))
    fourcc = int(capture.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little").decode().lower()
    fps = capture.get(cv2.CAP_PROP_FPS)
    capture.release()
    assert fourcc in {"avc1", "h264"}
    assert fps == pytest.approx(10.0)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.mp4"]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask, "a clip gets the usual file permissions"


def test_odd_sizes_are_padded_to_even(tmp_path: Path) -> None:
    path = tmp_path / "odd.mp4"
    with VideoWriter(path, fps=5, size=(W - 1, H - 1)) as video:
        video.write(frames(1, H - 1, W - 1)[0])
    assert next(read_video_frames(path)).shape == (H, W, 3)


def test_failure_inside_the_block_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "clip.mp4"
    with pytest.raises(RuntimeError, match="renderer broke"), VideoWriter(path, fps=10, size=(W, H)) as video:
        video.write(frames(1)[0])
        raise RuntimeError("renderer broke")
    assert list(tmp_path.iterdir()) == []


def test_wrong_frame_size_names_the_frame_and_leaves_no_file(tmp_path: Path) -> None:
    path = tmp_path / "clip.mp4"
    expected = r"frame 2 .* must be RGB uint8 of shape \(48, 64, 3\)"
    with pytest.raises(ValueError, match=expected), VideoWriter(path, fps=10, size=(W, H)) as video:
        for frame in [*frames(2), np.zeros((H, W + 2, 3), np.uint8)]:
            video.write(frame)
    assert list(tmp_path.iterdir()) == []


def test_empty_clip_and_missing_folder_are_errors(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no frames"), VideoWriter(tmp_path / "e.mp4", fps=10, size=(W, H)):
        pass
    assert list(tmp_path.iterdir()) == []
    with (
        pytest.raises(FileNotFoundError, match="nowhere"),
        VideoWriter(tmp_path / "nowhere" / "c.mp4", 10, (W, H)),
    ):
        pass


def test_reading_a_missing_or_broken_file_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="absent.mp4"):
        read_video_frames(tmp_path / "absent.mp4")
    broken = tmp_path / "broken.mp4"
    broken.write_bytes(b"not a video at all" * 10)
    with pytest.raises(ValueError, match="broken.mp4"):
        read_video_frames(broken)
