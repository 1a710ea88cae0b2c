"""The dynamic hold: a track keeps its boxes while the motion stage loses its target, for a while only."""

from __future__ import annotations

import numpy as np
import pytest

from spacetrack.motion.dynamic import DynamicHold
from spacetrack.tracking import DeepSort


def sort_tracker() -> DeepSort:
    return DeepSort(
        max_cosine_distance=None,
        nn_budget=None,
        max_iou_distance=0.7,
        max_age=1,
        n_init=3,
        min_confidence=0.0,
        nms_max_overlap=1.0,
    )


def run(hold: DynamicHold, frames: list[tuple[np.ndarray, np.ndarray]]) -> list[dict[int, np.ndarray]]:
    """Track (boxes, dynamic flags) per frame through the hold; the output tracks {id: tlwh} per frame."""
    tracker, out = sort_tracker(), []
    hold.reset()
    for boxes, dynamic in frames:
        keep = hold.keep(boxes, dynamic)
        tracks = tracker.step(boxes[keep], np.ones(int(keep.sum())))
        hold.update(tracks)
        out.append({int(t[0]): t[1:] for t in tracks})
    return out


def moving_target(num_frames: int, lost: range, stops_at: int | None = None) -> list[tuple]:
    """A 10x10 target moving 2 px a frame (not moving from `stops_at`), unseen by motion in `lost`, and a
    parked object that never moves."""
    frames = []
    for t in range(num_frames):
        x = 50 + 2 * (min(t, stops_at) if stops_at is not None else t)
        moving = t not in lost and (stops_at is None or t < stops_at)
        boxes = np.array([[x, 100, 10, 10], [300, 300, 12, 12]], dtype=float)
        frames.append((boxes, np.array([moving, False])))
    return frames


def test_a_target_lost_by_the_motion_stage_keeps_its_track_only_with_the_hold():
    frames = moving_target(40, lost=range(15, 22))
    paper = run(DynamicHold(frames=0), frames)
    held = run(DynamicHold(frames=10), frames)
    # The per-frame filter drops the target (the tracker shows a track one frame after its last match).
    assert all(len(paper[t]) == 0 for t in range(16, 22))
    assert {id for t in range(22, 40) for id in paper[t]} != {id for t in range(5, 15) for id in paper[t]}
    ids = [set(held[t]) for t in range(3, 40)]
    assert all(s == ids[0] for s in ids) and len(ids[0]) == 1  # one track, one id, every frame
    # The parked object never becomes a track, with or without the hold.
    assert not any(np.allclose(box, [300, 300, 12, 12]) for out in held for box in out.values())


def test_the_hold_lasts_at_most_its_frames_and_a_dynamic_box_renews_it():
    hold = DynamicHold(frames=5)
    frames = moving_target(40, lost=range(0), stops_at=10)
    out = run(hold, frames)
    assert all(len(out[t]) == 1 for t in range(3, 15))  # stopped at 10, held for frames 10-14
    assert all(len(out[t]) == 0 for t in range(16, 40))  # then dropped for good
    # Lost twice for 4 frames with a dynamic frame between: held through both gaps.
    out = run(DynamicHold(frames=5), moving_target(30, lost=set(range(10, 14)) | set(range(15, 19))))
    assert all(len(out[t]) == 1 for t in range(3, 30))


def test_without_tracks_or_without_static_boxes_the_flags_pass_unchanged():
    hold = DynamicHold(frames=30)
    boxes = np.array([[0, 0, 10, 10], [50, 50, 10, 10]], dtype=float)
    flags = np.array([True, False])
    assert hold.keep(boxes, flags).tolist() == [True, False]  # no track yet
    hold.update(np.array([[7, 0, 0, 10, 10]]))
    assert hold.keep(boxes, np.array([True, True])).tolist() == [True, True]
    # A static box far from every track stays out; one on the track is held.
    assert hold.keep(boxes, np.array([False, False])).tolist() == [True, False]
    assert hold.keep(np.zeros((0, 4)), np.zeros(0, bool)).tolist() == []


@pytest.mark.parametrize(("kwargs", "message"), [({"frames": -1}, "frames must be >= 0"),
                                                 ({"min_iou": 0.0}, "min_iou must lie in")])  # fmt: skip
def test_bad_settings_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        DynamicHold(**kwargs)
