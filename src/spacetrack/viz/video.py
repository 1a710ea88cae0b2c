"""MP4 clips: H.264 writing through the ffmpeg binary shipped by imageio-ffmpeg, reading through OpenCV.

H.264 in yuv420p with the index at the front of the file (`+faststart`) plays in browsers and in the
MLflow UI's artifact view, which OpenCV's own mp4v writer does not.
"""

from __future__ import annotations

import contextlib
import os
import subprocess
import tempfile
import uuid
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path
from types import TracebackType
from typing import IO

import cv2
import imageio_ffmpeg
import numpy as np


class VideoWriter:
    """Context manager writing RGB uint8 frames of `size` = (width, height) pixels to an MP4 at `path`.

    Frames go to a temporary sibling file that replaces `path` only when the block ends without error,
    so a failed write leaves no file. yuv420p needs even sizes: an odd width or height is padded with
    one black column or row in the file.

        with VideoWriter("clip.mp4", fps=10, size=(640, 480)) as video:
            for frame in frames:
                video.write(frame)
    """

    def __init__(self, path: str | Path, fps: float, size: tuple[int, int], *, crf: int = 20) -> None:
        self.path = Path(path)
        self.fps = fps
        self.size = (int(size[0]), int(size[1]))
        self.crf = crf
        self.frames_written = 0
        if fps <= 0:
            raise ValueError(f"fps must be positive, got {fps} (writing {self.path})")
        if min(self.size) < 1:
            raise ValueError(f"size must be (width, height) in pixels, got {size} (writing {self.path})")
        self._process: subprocess.Popen | None = None
        self._stderr: IO[bytes] | None = None
        self._tmp: Path | None = None

    def __enter__(self) -> VideoWriter:
        if not self.path.parent.is_dir():
            raise FileNotFoundError(
                f"output folder {self.path.parent} does not exist (writing {self.path.name})"
            )
        # ffmpeg creates the file itself, so it gets the usual permissions (mkstemp's would be 0600).
        self._tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}-{uuid.uuid4().hex[:8]}.tmp")
        width, height = self.size
        fps = str(Fraction(self.fps).limit_denominator(1001))
        command = [imageio_ffmpeg.get_ffmpeg_exe(), "-y", "-loglevel", "error"]
        command += ["-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}", "-r", fps, "-i", "-"]
        command += ["-an", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264", "-crf", str(self.crf)]
        command += ["-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4", str(self._tmp)]
        # ffmpeg's messages go to a file, not a pipe, so a chatty encoder can never block on a full pipe.
        self._stderr = tempfile.TemporaryFile()
        self._process = subprocess.Popen(command, stdin=subprocess.PIPE, stderr=self._stderr)
        return self

    def write(self, frame: np.ndarray) -> None:
        """Append one RGB uint8 frame of shape (height, width, 3)."""
        if self._process is None:
            raise RuntimeError(f"VideoWriter for {self.path} is not open; use it in a with block")
        width, height = self.size
        if frame.dtype != np.uint8 or frame.shape != (height, width, 3):
            raise ValueError(
                f"frame {self.frames_written} for {self.path} must be RGB uint8 of shape "
                f"({height}, {width}, 3), got {frame.dtype} {frame.shape}"
            )
        try:
            self._process.stdin.write(np.ascontiguousarray(frame).tobytes())
        except BrokenPipeError:
            raise RuntimeError(
                f"ffmpeg stopped at frame {self.frames_written} of {self.path}: {self._ffmpeg_says()}"
            ) from None
        self.frames_written += 1

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        assert self._process is not None and self._tmp is not None
        try:
            if exc_type is not None:
                self._process.kill()
            with contextlib.suppress(BrokenPipeError):
                self._process.stdin.close()  # end of input: ffmpeg finishes the file and exits
            returncode = self._process.wait()
            if exc_type is not None:
                return
            if self.frames_written == 0:
                raise ValueError(f"no frames were written to {self.path}")
            if returncode != 0:
                raise RuntimeError(f"ffmpeg failed writing {self.path}: {self._ffmpeg_says()}")
            os.replace(self._tmp, self.path)
        finally:
            self._tmp.unlink(missing_ok=True)
            self._stderr.close()
            self._process = None

    def _ffmpeg_says(self) -> str:
        self._process.wait()
        self._stderr.seek(0)
        return self._stderr.read().decode(errors="replace").strip() or f"exit code {self._process.returncode}"


def read_video_frames(path: str | Path) -> Iterator[np.ndarray]:
    """Iterate over the frames of the video at `path` as RGB uint8 arrays of shape (H, W, 3), in order.

    A missing or undecodable file is an error raised here, before iterating.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video {path} does not exist")
    capture = cv2.VideoCapture(str(path))
    ok, first = capture.read() if capture.isOpened() else (False, None)
    if not ok:
        capture.release()
        raise ValueError(f"cannot read video {path}: OpenCV could not decode its first frame")
    return _frames(capture, first)


def _frames(capture: cv2.VideoCapture, first: np.ndarray) -> Iterator[np.ndarray]:
    try:
        frame: np.ndarray | None = first
        while frame is not None:
            yield cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
            ok, frame = capture.read()
            frame = frame if ok else None
    finally:
        capture.release()
