"""The streaming stages: a frame's detections wait for its own motion mask, in order, none lost."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from spacetrack.motion import DynamicFilter
from spacetrack.motion.blobs import Blob
from spacetrack.pipeline.sources import FrameSource
from spacetrack.pipeline.stages import DetectionStream, detection_rows


class OneBoxDetector:
    """A box at x = 10 * frame in every frame but the fifth, which has none."""

    def begin(self, source):
        pass

    def __call__(self, rgb, frame):
        if frame == 5:
            return np.zeros((0, 6))
        return np.array([[10.0 * frame, 5, 4, 4, 0.9, 1]])


class LaggingMotion:
    """Like the five-frame difference: latency 2, first mask for the third frame; its only blob sits on
    the box of the frame it answers for."""

    latency = 2

    def reset(self):
        self.count, self.mask_index, self.blobs = 0, -1, []

    def apply(self, frame):
        self.thread = threading.current_thread().name
        if not frame.any() and frame.shape[0] == 1:
            raise ValueError("frame 1 px high")
        self.count += 1
        if self.count < 2 * self.latency + 1:
            return None
        self.mask_index = self.count - 1 - self.latency
        x = 10.0 * (self.mask_index + 1)
        self.blobs = [Blob((x + 2, 7.0), (int(x), 5, 4, 4), 16.0)]
        return np.zeros((2, 2), np.uint8)


def _source(n: int) -> FrameSource:
    frames = (np.zeros((20, 100, 3), np.uint8) for _ in range(n))
    return FrameSource("fake", "fake frames", 10.0, n, frames)


def _stream(**changes) -> DetectionStream:
    """A stream of identity enhancement, `OneBoxDetector`, no encoder, no motion, a default filter, with
    `changes` to any of those."""
    kwargs = dict(enhancer=lambda rgb: rgb, detector=OneBoxDetector(), encoder=None, motion=None,
                  dynamic_filter=DynamicFilter())  # fmt: skip
    return DetectionStream(**(kwargs | changes))


@pytest.mark.parametrize(
    ("overlap", "overlap_reid"), [(True, True), (True, False), (False, True), (False, False)]
)
def test_detections_are_paired_with_the_blobs_of_their_own_frame(overlap, overlap_reid):
    motion = LaggingMotion()
    threads = set()

    def encoder(rgb, boxes):  # like the Encoder: (0, D) for no box
        threads.add(threading.current_thread().name)
        return np.ones((len(boxes), 3))

    stream = _stream(
        encoder=encoder,
        motion=motion,
        dynamic_filter=DynamicFilter(min_overlap=0.5, max_distance=0.0),
        overlap_motion=overlap,
        overlap_reid=overlap_reid,
    )
    out = list(stream.run(_source(6), keep_images=True))
    # overlapped, the motion stage and the re-ID run in threads of their own; the answers are the same
    assert (motion.thread == threading.current_thread().name) is not overlap
    assert (threads == {threading.current_thread().name}) is not overlap_reid
    assert [f.frame for f in out] == [1, 2, 3, 4, 5, 6]
    # Frames 1-4 get masks of their own frame (1 and 2 wait for frame 3's, whose blob is elsewhere);
    # 5 (no detection at all) and 6 never get one and take frame 4's blob, which is elsewhere too.
    assert [f.dynamic.tolist() for f in out] == [[False], [False], [True], [True], [], [False]]
    assert out[4].rows.shape == (0, 13)
    assert out[0].rows.shape == (1, 13) and out[0].image.shape == (20, 100, 3)
    assert out[3].classes.tolist() == [1] and stream.latency == 2 + overlap_reid


def test_an_error_in_the_overlapped_motion_stage_reaches_the_caller():
    stream = _stream(motion=LaggingMotion())
    bad = FrameSource("bad", "bad frames", 10.0, 2, iter([np.zeros((1, 4, 3), np.uint8)] * 2))
    with pytest.raises(ValueError, match="1 px high"):
        list(stream.run(bad))


def test_without_motion_every_detection_is_dynamic():
    stream = _stream()
    out = list(stream.run(_source(3)))
    assert all(f.dynamic.all() for f in out) and out[0].rows.shape == (1, 10) and out[0].image is None
    assert set(stream.timer.seconds) >= {"detector", "reid"}


def test_detection_rows_follow_the_design_layout():
    rows = detection_rows(7, np.array([[1.0, 2, 3, 4, 0.5, 2]]), np.array([[0.6, 0.8]]))
    assert rows.tolist() == [[7, -1, 1, 2, 3, 4, 0.5, -1, -1, -1, 0.6, 0.8]]


class CountingEncoder:
    """A feature of ones for every box it is given; counts the boxes it encoded."""

    feature_dim = 3

    def __init__(self):
        self.encoded = 0

    def __call__(self, rgb, boxes):
        self.encoded += len(boxes)
        return np.ones((len(boxes), self.feature_dim), np.float32)


class ScoredBoxes:
    """Three boxes per frame scoring 0.1, 0.3 and 0.9."""

    def begin(self, source):
        pass

    def __call__(self, rgb, frame):
        return np.array([[0.0, 0, 4, 4, 0.1, 0], [10, 0, 4, 4, 0.3, 0], [20, 0, 4, 4, 0.9, 0]])


def test_only_detections_at_or_above_the_reid_min_score_are_encoded():
    encoder = CountingEncoder()
    stream = _stream(detector=ScoredBoxes(), encoder=encoder, reid_min_score=0.3)
    out = list(stream.run(_source(2)))
    assert encoder.encoded == 4  # two boxes in each of two frames
    features = out[0].rows[:, 10:]
    assert features.tolist() == [[0, 0, 0], [1, 1, 1], [1, 1, 1]]


class RecordingDetector(OneBoxDetector):
    """Sets an event for each frame as the detector starts on it."""

    def __init__(self):
        self.started = {k: threading.Event() for k in range(1, 10)}

    def __call__(self, rgb, frame):
        self.started[frame].set()
        return super().__call__(rgb, frame)


def test_overlapped_reid_encodes_a_frame_while_the_detector_works_on_the_next():
    detector = RecordingDetector()
    seen_next = []

    class WaitingEncoder:
        feature_dim = 3
        frame = 0

        def __call__(self, rgb, boxes):
            self.frame += 1  # called for every frame, also with no box
            # encoding frame t: the detector starts frame t + 1 meanwhile (the last frame has no next one)
            seen_next.append(self.frame == 6 or detector.started[self.frame + 1].wait(timeout=10))
            return np.ones((len(boxes), 3), np.float32)

    out = list(_stream(detector=detector, encoder=WaitingEncoder()).run(_source(6)))
    assert [f.frame for f in out] == [1, 2, 3, 4, 5, 6] and seen_next == [True] * 6
    assert out[0].rows[:, 10:].tolist() == [[1, 1, 1]]


def test_an_error_in_the_overlapped_reid_reaches_the_caller():
    def failing(rgb, boxes):
        raise RuntimeError("re-ID failed on purpose")

    with pytest.raises(RuntimeError, match="on purpose"):
        list(_stream(encoder=failing).run(_source(3)))


def test_the_blob_test_takes_min_share_of_best_in_track_mode_only():
    from spacetrack.config import compose_config
    from spacetrack.pipeline.build import build_dynamic_filter

    track = compose_config("track", ["dynamic_filter=track", "dynamic_track.min_share_of_best=0.4"])
    assert build_dynamic_filter(track).min_share_of_best == 0.4
    frame = compose_config("track", ["dynamic_filter=frame", "dynamic_track.min_share_of_best=0.4"])
    assert build_dynamic_filter(frame).min_share_of_best == 0.0  # the paper's per-frame test
