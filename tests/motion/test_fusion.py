import cv2
import numpy as np
import pytest

from spacetrack.motion import KNN, MOG2, FiveFrameDifference, Fusion, ViBe
from spacetrack.motion.fusion import confirmed_regions, fill_regions, filled_hull


def _fusion(**kwargs) -> Fusion:
    return Fusion(difference=FiveFrameDifference(), background=ViBe(), **kwargs)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return (a & b).sum() / (a | b).sum()


def test_square_moving_over_black_field_gives_one_blob_per_frame(scene, run):
    frames, truth = scene(10)
    fusion = _fusion()
    assert fusion.latency == 2
    masks = {}
    for frame in frames:
        mask = fusion.apply(frame)
        if mask is not None:
            masks[fusion.mask_index] = mask > 0
            assert len(fusion.blobs) == 1
            cx, cy = fusion.blobs[0].centroid
            x, y = np.argwhere(truth[fusion.mask_index].T).mean(axis=0)
            assert abs(cx - x) < 1 and abs(cy - y) < 1
    assert sorted(masks) == list(range(2, 8))
    # ViBe's ghost at the starting place (frame 0 is in its model) is not in the fusion
    assert all(_iou(m, truth[t]) > 0.8 for t, m in masks.items())


def test_flash_and_stop_leave_nothing(scene, run):
    frames, _ = scene(12, velocity=(0, 0), flash_at=5)
    assert not any(m.any() for m in run(_fusion(), frames).values())
    frames, _ = scene(14, stop_at=5)
    masks = run(_fusion(), frames)
    assert masks[4].any()
    assert not any(masks[t].any() for t in range(7, 12))


def test_masks_of_detectors_with_different_start_are_paired_by_frame(scene):
    frames, _ = scene(8)
    fusion = Fusion(difference=FiveFrameDifference(), background=MOG2())
    indices = []
    for frame in frames:
        if fusion.apply(frame) is not None:
            indices.append(fusion.mask_index)
    # the five-frame difference has its first mask at frame 2, once frame 4 is in
    assert indices == [2, 3, 4, 5]
    assert Fusion(difference=KNN(), background=ViBe()).latency == 0


def test_fill_regions_fills_holes_and_drops_small_regions():
    mask = np.zeros((12, 12), np.uint8)
    mask[2:9, 2:9] = 255
    mask[4:7, 4:7] = 0
    mask[0:2, 10:12] = 255  # a 2x2 region: its outline encloses 1 px²
    filled = fill_regions(mask, min_area=2)
    assert (filled[2:9, 2:9] == 255).all()
    assert filled.sum() == 49 * 255
    assert (fill_regions(mask)[0:2, 10:12] == 255).all()


def test_fusion_beats_its_parts_on_a_textured_target_with_stars(scene, run):
    frames, truth = scene(40, size=10, velocity=(3, 1), stars=((5, 5), (80, 50), (40, 60)), noise=4.0)
    scores = {}
    for name, detector in (("five", FiveFrameDifference()), ("vibe", ViBe()), ("fusion", _fusion())):
        masks = run(detector, frames)
        tp = sum((m & truth[t]).sum() for t, m in masks.items())
        fp = sum((m & ~truth[t]).sum() for t, m in masks.items())
        fn = sum((~m & truth[t]).sum() for t, m in masks.items())
        scores[name] = 2 * tp / (2 * tp + fp + fn)
    assert scores["fusion"] > max(scores["five"], scores["vibe"])


def test_confirmed_regions_keeps_whole_regions_with_enough_evidence():
    body = np.zeros((20, 30), np.uint8)
    body[2:10, 2:10] = 255
    body[5:7, 5:7] = 0  # a hole: filled in the output
    body[12:18, 20:28] = 255  # no evidence: dropped
    evidence = np.zeros_like(body)
    evidence[2, 2:5] = 255  # three pixels on the first region's rim
    evidence[0, 29] = 255  # evidence outside any region: ignored
    out = confirmed_regions(body, evidence, min_support=3)
    assert (out[2:10, 2:10] == 255).all() and out.sum() == 64 * 255
    assert not confirmed_regions(body, evidence, min_support=4).any()


def test_confirmed_regions_cut_to_the_hull_of_dense_evidence_only():
    body = np.zeros((12, 40), np.uint8)
    body[2:10, 2:32] = 255  # a target (left) joined to a ghost (right)
    evidence = np.zeros_like(body)
    evidence[2:10, 2:10] = 255  # 64 of the region's 240 pixels
    cut = confirmed_regions(body, evidence, hull_margin=2, hull_min_fill=0.25)
    assert (cut[2:10, 2:12] == 255).all() and not cut[:, 12:].any() and not cut[:2].any()
    assert (confirmed_regions(body, evidence, hull_margin=0, hull_min_fill=0.25) == evidence).all()
    whole = confirmed_regions(body, evidence)
    assert (whole == body).all()
    assert (confirmed_regions(body, evidence, hull_margin=2, hull_min_fill=0.3) == whole).all()  # sparse


def test_filled_hull_from_row_ends_is_the_hull_of_every_pixel():
    rng = np.random.default_rng(3)
    for density in (0.002, 0.05, 0.5):
        mask = np.where(rng.random((40, 60)) < density, 255, 0).astype(np.uint8)
        mask[rng.integers(40), rng.integers(60)] = 255  # never empty
        every = cv2.fillConvexPoly(np.zeros_like(mask), cv2.convexHull(cv2.findNonZero(mask)), 255)
        assert np.array_equal(filled_hull(mask), every)
    line = np.zeros((9, 9), np.uint8)
    line[4, 2:7] = 255  # one row: a segment, grown into a rounded bar
    grown = filled_hull(line, 2)
    assert grown[4].all() and grown[2:7, 2:7].all()  # 2 px on every side of the segment
    assert not grown[:2].any() and not grown[7:].any() and not grown[2, :2].any()  # and no further; rounded


def test_hull_cut_drops_the_start_up_ghost_joined_to_a_target(scene):
    # The square stands in ViBe's first frame: where it was stays 'moving' (a ghost) until ViBe absorbs
    # it, joined to the square while the square is still leaving its starting place.
    frames, truth = scene(14, size=16, start=(10, 20), velocity=(3, 0))
    counts = {}
    for margin in (None, 3):
        fusion = _fusion(hull_margin=margin, hull_min_fill=0.2)
        counts[margin] = masks = {}
        for frame in frames:
            mask = fusion.apply(frame)
            if mask is not None:
                masks[fusion.mask_index] = mask > 0
    false = {m: sum((k & ~truth[t]).sum() for t, k in masks.items()) for m, masks in counts.items()}
    missed = {m: sum((~k & truth[t]).sum() for t, k in masks.items()) for m, masks in counts.items()}
    assert false[3] < 0.7 * false[None]
    assert missed[3] - missed[None] < 0.5 * (false[None] - false[3])
    assert all(np.array_equal(counts[3][t], counts[None][t]) for t in counts[3] if t >= 7)  # ghost gone


def test_hull_settings_are_checked():
    with pytest.raises(ValueError, match="hull_margin"):
        _fusion(hull_margin=-1)
    with pytest.raises(ValueError, match="hull_min_fill"):
        _fusion(hull_margin=3, hull_min_fill=1.5)


def test_parallel_fusion_gives_the_same_masks_and_blobs_as_in_turn(scene):
    frames, _ = scene(30, size=10, velocity=(3, 1), stars=((5, 5), (80, 50)), noise=4.0)
    in_turn, parallel = _fusion(), _fusion(parallel=True)
    for _ in range(2):  # and again after a reset
        for frame in frames:
            a, b = in_turn.apply(frame), parallel.apply(frame)
            assert (a is None) == (b is None)
            if a is not None:
                assert parallel.mask_index == in_turn.mask_index
                assert np.array_equal(a, b) and parallel.blobs == in_turn.blobs
        in_turn.reset()
        parallel.reset()
    parallel.close()
    assert parallel.apply(frames[0]) is None  # a closed fusion starts a new worker when used again


def test_parallel_fusion_reports_a_bad_frame_with_its_index(scene):
    frames, _ = scene(6)
    fusion = _fusion(parallel=True)
    for frame in frames[:3]:
        fusion.apply(frame)
    with pytest.raises(ValueError, match="frame 3"):
        fusion.apply(frames[3][:32])
    fusion.close()


def test_parallel_fusion_is_unaffected_by_a_caller_that_reuses_its_frame_buffer(scene):
    # The background model may still read the frame after `apply` returns: a video reader that decodes
    # into one buffer must not change what it sees (grey input reaches it without a conversion copy).
    frames, _ = scene(20, size=10, velocity=(3, 1), noise=4.0)
    in_turn, parallel = _fusion(), _fusion(parallel=True)
    buffer = np.empty_like(frames[0])
    for frame in frames:
        buffer[...] = frame
        b = parallel.apply(buffer)
        buffer[...] = 255  # the next decode starts at once
        a = in_turn.apply(frame)
        assert (a is None) == (b is None)
        if a is not None:
            assert np.array_equal(a, b) and parallel.blobs == in_turn.blobs
    parallel.close()


def test_parallel_fusion_waits_for_a_background_model_that_answers_later_than_the_difference(scene):
    # Two-frame difference (latency 0) and ViBe (latency 0): every mask needs the frame still in flight.
    from spacetrack.motion import TwoFrameDifference

    frames, _ = scene(12, size=10, velocity=(3, 1))

    def fusion(**kwargs) -> Fusion:
        return Fusion(difference=TwoFrameDifference(threshold=10), background=ViBe(), **kwargs)

    in_turn, parallel = fusion(), fusion(parallel=True)
    pairs = [(in_turn.apply(f), parallel.apply(f), in_turn.mask_index, parallel.mask_index) for f in frames]
    assert sum(a is not None for a, *_ in pairs) == len(frames) - 1
    for a, b, i, j in pairs:
        assert (a is None) == (b is None) and i == j
        assert a is None or np.array_equal(a, b)
    parallel.close()


class _Broken(ViBe):
    def apply(self, frame: np.ndarray) -> np.ndarray | None:
        if self._guard.count == 4:
            raise RuntimeError("model failed on frame 4")
        return super().apply(frame)


def test_parallel_fusion_raises_what_its_background_model_raised(scene):
    frames, _ = scene(8)
    fusion = Fusion(difference=FiveFrameDifference(), background=_Broken(), parallel=True)
    for frame in frames[:5]:  # frame 4 goes to the worker; the call returns before it fails
        fusion.apply(frame)
    with pytest.raises(RuntimeError, match="frame 4"):
        fusion.flush()
    fusion.reset()  # starts over: the failure is forgotten
    assert all(fusion.apply(frame) is None for frame in frames[:2])
    fusion.close()
