"""Where frames come from: a rendered sequence, a folder of frames, a video file, a camera, a RealSense.

Every source yields RGB uint8 (H, W, 3) frames in order and refuses a frame whose size differs from the
first one's, naming the source and the 1-based frame number. Live sources (cameras) have no length.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from spacetrack.data.layout import frame_paths, read_rgb

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v")


class SourceError(ValueError):
    """A source that cannot be read as promised; the message names the source and the frame."""


@dataclass
class FrameSource:
    """A named stream of RGB frames. `num_frames` is None for live sources; `fps` is frames per second;
    `files` the files the frames are read from (the images in order, or the video file; none for a live
    source), whose bytes key the detection cache."""

    name: str
    description: str
    fps: float
    num_frames: int | None
    frames: Iterator[np.ndarray] = field(repr=False)
    live: bool = False
    files: tuple[Path, ...] = ()

    def __iter__(self) -> Iterator[np.ndarray]:
        shape = None
        for number, frame in enumerate(self.frames, start=1):
            if shape is None:
                shape = frame.shape
            elif frame.shape != shape:
                raise SourceError(
                    f"{self.description}: frame {number} is {frame.shape[1]}x{frame.shape[0]} but the "
                    f"first frame was {shape[1]}x{shape[0]}; a stream must keep one frame size"
                )
            yield frame


def _image_frames(paths: list[Path]) -> Iterator[np.ndarray]:
    for path in paths:
        yield read_rgb(path)


def sequence_source(root: str | Path, seq: str, *, image_dir: str = "img", fps: float = 10.0) -> FrameSource:
    """Frames `root/seq/<image_dir>/000001.jpg ...` of a rendered sequence (or any folder of such)."""
    paths = frame_paths(root, seq, image_dir)
    description = str(Path(root) / seq / image_dir)
    return FrameSource(seq, description, fps, len(paths), _image_frames(paths), files=tuple(paths))


def folder_source(folder: str | Path, *, fps: float = 10.0) -> FrameSource:
    """The .jpg/.png images of `folder` in name order."""
    folder = Path(folder)
    paths = frame_paths(folder.parent, folder.name, ".")
    return FrameSource(
        folder.name, f"folder {folder}", fps, len(paths), _image_frames(paths), files=tuple(paths)
    )


def _capture_frames(
    capture: cv2.VideoCapture, description: str, expected: int | None
) -> Iterator[np.ndarray]:
    count = 0
    try:
        while True:
            ok, bgr = capture.read()
            if not ok:
                break
            count += 1
            yield cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
    finally:
        capture.release()
    if expected and count < expected:
        raise SourceError(f"{description}: truncated or corrupt, decoded {count} of {expected} frames")


def video_source(path: str | Path, *, fps: float | None = None) -> FrameSource:
    """Frames of a video file, decoded by OpenCV; an unreadable or truncated file is a SourceError."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video {path} does not exist")
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        capture.release()
        raise SourceError(f"video {path}: OpenCV cannot open it (unreadable, truncated or not a video)")
    count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    rate = fps or capture.get(cv2.CAP_PROP_FPS) or 10.0
    frames = _capture_frames(capture, f"video {path}", count if count > 0 else None)
    total = count if count > 0 else None
    return FrameSource(path.stem, f"video {path}", float(rate), total, frames, files=(path,))


def camera_source(index: int, *, fps: float | None = None) -> FrameSource:
    """Frames of camera `index` (OpenCV); a missing camera is a SourceError."""
    capture = cv2.VideoCapture(index)
    ok = capture.isOpened() and capture.grab()
    if not ok:
        capture.release()
        raise SourceError(f"camera {index} is not available (no device, or it is busy)")
    rate = fps or capture.get(cv2.CAP_PROP_FPS) or 30.0
    frames = _capture_frames(capture, f"camera {index}", None)
    return FrameSource(f"camera{index}", f"camera {index}", float(rate), None, frames, live=True)


def realsense_source(*, width: int = 640, height: int = 480, fps: int = 30) -> FrameSource:
    """The colour stream of an Intel RealSense (D435i) through the optional `pyrealsense2`."""
    try:
        import pyrealsense2 as rs
    except ImportError:
        raise SourceError(
            "source=realsense needs the optional package pyrealsense2 (pip install pyrealsense2)"
        ) from None
    pipeline, config = rs.pipeline(), rs.config()
    config.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
    try:
        pipeline.start(config)
    except RuntimeError as err:
        raise SourceError(f"RealSense camera is not available: {err}") from err

    def frames() -> Iterator[np.ndarray]:
        try:
            while True:
                colour = pipeline.wait_for_frames().get_color_frame()
                yield np.asanyarray(colour.get_data()).copy()
        finally:
            pipeline.stop()

    return FrameSource("realsense", "RealSense colour stream", float(fps), None, frames(), live=True)


def limit(source: FrameSource, max_frames: int | None) -> FrameSource:
    """`source` cut to its first `max_frames` frames (None: all of them)."""
    if max_frames is None:
        return source
    total = max_frames if source.num_frames is None else min(max_frames, source.num_frames)
    return replace(source, frames=itertools.islice(source.frames, max_frames), num_frames=total)


def open_source(spec: str | int, *, fps: float | None = None) -> FrameSource:
    """A source from a command-line value: a camera index (`0`), `realsense`, a video file, or a folder
    of frames (a rendered sequence's folder is read from its `img/`)."""
    text = str(spec)
    if text.isdigit():
        return camera_source(int(text), fps=fps)
    if text == "realsense":
        return realsense_source()
    path = Path(text)
    if path.is_dir():
        if (path / "img").is_dir():
            return sequence_source(path.parent, path.name, fps=fps or 10.0)
        return folder_source(path, fps=fps or 10.0)
    if path.suffix.lower() in VIDEO_SUFFIXES or path.is_file():
        return video_source(path, fps=fps)
    raise FileNotFoundError(
        f"source {text!r} is neither a camera index, 'realsense', a video file nor a folder of frames"
    )
