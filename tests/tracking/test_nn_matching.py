import numpy as np
import pytest

from spacetrack.tracking.nn_matching import NearestNeighborDistanceMetric


def _unit(x):
    return x / np.linalg.norm(x, axis=-1, keepdims=True)


def _brute_force(galleries, target, queries):
    g = _unit(np.array(galleries[target]))
    return (1 - g @ _unit(queries).T).min(axis=0)


@pytest.mark.parametrize("budget", [3, None])
def test_distance_is_min_cosine_distance_over_the_latest_budget_features(budget):
    rng = np.random.default_rng(0)
    metric = NearestNeighborDistanceMetric(max_cosine_distance=0.2, nn_budget=budget)
    galleries = {1: [], 2: [], 3: []}
    for frame in range(40):
        active = [1, 2] if frame < 20 else [1, 2, 3]
        feats, targets = [], []
        for t in active:
            for _ in range(int(rng.integers(0, 3))):
                feats.append(_unit(rng.normal(size=8)))
                targets.append(t)
                galleries[t].append(feats[-1])
        metric.partial_fit(np.array(feats).reshape(-1, 8), np.array(targets, dtype=int), active)
        for t in active:
            if budget is not None:
                galleries[t] = galleries[t][-budget:]
        queries = _unit(rng.normal(size=(4, 8)))
        present = [t for t in active if galleries[t]]
        if present:
            got = metric.distance(queries, present)
            expected = np.stack([_brute_force(galleries, t, queries) for t in present])
            np.testing.assert_allclose(got, expected, atol=1e-12)
            for t in present:
                assert len(metric.samples(t)) == len(galleries[t])


def test_inactive_tracks_are_forgotten():
    metric = NearestNeighborDistanceMetric(max_cosine_distance=0.2, nn_budget=10)
    metric.partial_fit(np.eye(3), np.array([1, 2, 3]), [1, 2, 3])
    metric.partial_fit(np.zeros((0, 3)), np.zeros(0, dtype=int), [2])
    with pytest.raises(KeyError):
        metric.distance(np.eye(3), [1])
    np.testing.assert_allclose(metric.distance(np.eye(3), [2]), [[1.0, 0.0, 1.0]])


def test_only_admissible_pairs_are_computed_and_the_rest_are_inf():
    rng = np.random.default_rng(2)
    metric = NearestNeighborDistanceMetric(max_cosine_distance=0.2, nn_budget=5)
    gallery = _unit(rng.normal(size=(12, 6)))
    targets = np.repeat([4, 8, 9], 4)
    metric.partial_fit(gallery, targets, [4, 8, 9])
    queries = _unit(rng.normal(size=(7, 6)))
    admissible = rng.random((3, 7)) < 0.4
    admissible[1] = False  # a track with nothing in its gate
    got = metric.distance(queries, [4, 8, 9], admissible)
    full = metric.distance(queries, [4, 8, 9])
    np.testing.assert_allclose(got[admissible], full[admissible], atol=1e-12)
    assert np.isinf(got[~admissible]).all()
    expected = np.stack([(1 - gallery[targets == t] @ queries.T).min(axis=0) for t in [4, 8, 9]])
    np.testing.assert_allclose(full, expected, atol=1e-12)
