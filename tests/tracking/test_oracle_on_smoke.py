"""The tracker and the scorer on the rendered smoke dataset, fed its own ground truth as detections.

With perfect boxes and one distinct appearance per target, what is lost is only what the tracker
rules cost: the first n_init - 1 frames of every track, and Kalman boxes of tiny targets that lag
their ground truth. Scores far below that mean the dataset, the tracker and the scorer disagree on
a format (frames, box convention, the conf column of hidden targets).
"""

import numpy as np
import pytest
from hydra.utils import instantiate

from spacetrack.config import compose_config
from spacetrack.data.layout import read_mot
from spacetrack.evaluation import OVERALL, evaluate
from spacetrack.track_detections import rows_as_mot
from spacetrack.tracking import track_sequence


def oracle_detections(gt: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """DeepSORT-layout detections from the visible ground-truth rows, features one-hot per target id."""
    visible = gt[gt[:, 6] == 1]
    features = np.eye(32)[visible[:, 1].astype(int) % 32] + rng.normal(0, 0.02, (len(visible), 32))
    head = np.column_stack(
        [visible[:, 0], -np.ones(len(visible)), visible[:, 2:6], np.full(len(visible), 0.9)]
    )
    return np.hstack([head, -np.ones((len(visible), 3)), features])


@pytest.mark.slow
def test_oracle_detections_track_almost_perfectly(smoke_dataset):
    rng = np.random.default_rng(0)
    cfg = compose_config("track_detections", ["tracker=deepsort_original", "logger=none"])
    sequences = {}
    for seq_dir in sorted(smoke_dataset.glob("seq_*")):
        gt = read_mot(seq_dir / "gt" / "gt.txt")
        assert (gt[:, 6] == 0).sum() < len(gt) / 2  # mostly visible rows (the occlusion clip hides a quarter)
        rows = track_sequence(instantiate(cfg.tracker), oracle_detections(gt, rng))
        sequences[seq_dir.name] = (gt, rows_as_mot(rows))
    scores = evaluate(sequences)
    overall = scores[OVERALL]
    assert overall["mota"] > 0.75 and overall["idf1"] > 0.8, overall
    assert overall["idsw"] <= len(sequences), overall
