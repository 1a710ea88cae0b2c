"""Same detections, same settings: our tracks equal those of a public port of the reference DeepSORT.

The peer (`deep-sort-realtime`, installed with --no-deps by the Makefile's setup step) is not a package dependency, so this test
runs only where it is installed. The peer re-adds each track's last feature to its gallery every frame
and skips the confidence sort when NMS is off, so the comparison uses unbounded galleries and hands it
detections already sorted by confidence; everything else is the reference algorithm.
"""

import numpy as np
import pytest
import scipy.linalg  # noqa: F401  (loaded before pinning, so its BLAS is pinned too)
from threadpoolctl import threadpool_limits

from spacetrack.tracking import DeepSort

peer_module = pytest.importorskip("deep_sort_realtime.deepsort_tracker")


def _frames(seed, num_targets=15, num_frames=80, dim=32):
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(num_targets, dim))
    start = rng.uniform(50, 450, size=(num_targets, 2))
    velocity = rng.normal(0, 3, size=(num_targets, 2))
    for f in range(num_frames):
        seen = rng.random(num_targets) > 0.15
        xy = start[seen] + velocity[seen] * f + rng.normal(0, 1.5, size=(seen.sum(), 2))
        wh = rng.normal([30, 40], 1.5, size=(seen.sum(), 2))
        confidence = rng.uniform(0.2, 1.0, seen.sum())
        feature = means[seen] + rng.normal(0, 0.4, size=(seen.sum(), dim))
        order = np.argsort(-confidence, kind="stable")
        yield np.hstack([xy, wh])[order], confidence[order], feature[order]


@pytest.mark.parametrize(
    "settings",
    [
        dict(max_cosine_distance=0.2, max_iou_distance=0.7, max_age=30, n_init=3, nms_max_overlap=0.5),
        dict(max_cosine_distance=0.1, max_iou_distance=0.5, max_age=70, n_init=6, nms_max_overlap=1.0),
    ],
)
def test_tracks_equal_the_reference_port(settings):
    # one BLAS thread: on a busy machine threaded OpenBLAS stalls the peer's tiny triangular solves
    with threadpool_limits(limits=1, user_api="blas"):
        _compare(settings)


def _compare(settings):
    ours = DeepSort(**settings, nn_budget=None, min_confidence=0.0)
    peer = peer_module.DeepSort(**settings, nn_budget=None, embedder=None)
    written = 0
    for tlwh, confidence, feature in _frames(seed=3):
        got = {int(r[0]): r[1:] for r in ours.step(tlwh, confidence, feature)}
        raw = [(list(box), float(c), 0) for box, c in zip(tlwh, confidence, strict=True)]
        tracks = peer.update_tracks(raw, embeds=list(feature))
        expected = {
            int(t.track_id): t.to_tlwh() for t in tracks if t.is_confirmed() and t.time_since_update <= 1
        }
        assert got.keys() == expected.keys()
        for k, box in got.items():
            np.testing.assert_allclose(box, expected[k], atol=1e-2)  # the peer keeps float32 boxes
        written += len(got)
    assert written > 600
