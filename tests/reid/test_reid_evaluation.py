"""Held-out metrics on features whose answers are worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from spacetrack.reid.evaluation import evaluate_features, gallery_distances, pair_distances, retrieval


def unit(angles_deg) -> np.ndarray:
    a = np.radians(angles_deg)
    return np.stack([np.cos(a), np.sin(a)], axis=1)


def test_retrieval_rank1_and_map_by_hand() -> None:
    # identity 0 at 0 and 10 degrees, identity 1 at 5 and 90 degrees, frames far apart
    features = unit([0, 10, 5, 90])
    identity = np.array([0, 0, 1, 1])
    frame = np.array([1, 50, 1, 50])
    out = retrieval(features, identity, frame, exclude_frames=10)
    # q0: 5(1) 10(0) 90(1) -> rank1 miss, AP 1/2; q1: 5(1) 0(0) -> miss, AP 1/2
    # q2: 0(0) 10(0) 90(1) -> miss, AP 1/3;        q3: 10(0) 5(1) -> miss, AP 1/2
    assert out["rank1"] == 0.0
    assert out["mAP"] == pytest.approx((0.5 + 0.5 + 1 / 3 + 0.5) / 4)
    # moving identity 1's second crop next to its first makes every query hit first
    out = retrieval(unit([0, 10, 60, 61]), identity, frame, exclude_frames=10)
    assert out["rank1"] == 1.0 and out["mAP"] == 1.0


def test_retrieval_leaves_near_frames_of_the_same_target_out() -> None:
    features = unit([0, 0, 3])
    identity = np.array([0, 0, 1])
    with pytest.raises(ValueError, match="no query"):
        retrieval(features, identity, np.array([1, 2, 1]), exclude_frames=5)
    out = retrieval(features, identity, np.array([1, 2, 1]), exclude_frames=1)
    assert out["queries"] == 2 and out["rank1"] == 1.0


def test_pair_and_gallery_distances_by_hand() -> None:
    features = unit([0, 60, 90, 0])
    identity = np.array([0, 0, 1, 2])
    sequence = np.array([0, 0, 0, 1])
    frame = np.array([1, 2, 1, 1])
    same, diff = pair_distances(features, identity, sequence)
    np.testing.assert_allclose(same, [0.5])  # 1 - cos 60
    # id 0 (0 and 60 degrees) vs id 1 (90 degrees) in the same sequence; id 2 is in another one
    np.testing.assert_allclose(np.sort(diff), [1 - np.cos(np.radians(30)), 1.0])
    g_same, g_other = gallery_distances(features, identity, sequence, frame, window=1)
    # only the crop of frame 2 has a gallery (frame 1): its own identity at 0.5, identity 1 at 1 - cos 30
    np.testing.assert_allclose(g_same, [0.5])
    np.testing.assert_allclose(g_other, [1 - np.cos(np.radians(30))])


def test_evaluate_features_reports_the_gate_fractions() -> None:
    features = unit([0, 5, 40, 44, 120, 121])
    identity = np.array([0, 0, 1, 1, 2, 2])
    metrics, arrays = evaluate_features(
        features,
        identity,
        np.zeros(6, int),
        np.array([1, 2, 1, 2, 1, 2]),
        exclude_frames=1,
        window=5,
        thresholds=[0.1],
    )
    assert metrics["rank1"] == 1.0
    # same pairs: 1-cos5, 1-cos4, 1-cos1, all below 0.1; different pairs: none below 0.1
    assert metrics["pair_same_below_0.1"] == 1.0 and metrics["pair_diff_below_0.1"] == 0.0
    assert metrics["gallery_same_below_0.1"] == 1.0
    assert set(arrays) == {"pair_same", "pair_diff", "gallery_same", "gallery_diff"}
