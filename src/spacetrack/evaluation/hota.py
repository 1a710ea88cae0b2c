"""HOTA, DetA, AssA and LocA through TrackEval's `HOTA` metric, on in-memory MOT arrays.

TrackEval (the metric's reference implementation) reads benchmark folders through its dataset classes;
here only its metric class is used, on the per-frame dict its `eval_sequence` takes, built from our
(N, 9) MOT arrays `frame,id,x,y,w,h,conf,class,visibility` (boxes `tlwh`, pixels). The similarity is the
IoU of the boxes. Ground-truth rows that `mot.ignored_rows` ignores are left out the way MOTChallenge's
preprocessing does it (the same rule as for MOTA): a hypothesis the frame's optimal assignment pairs with
one of them is dropped, then the rows themselves. Every score is the mean over TrackEval's 19
localisation thresholds alpha = 0.05, 0.10, ..., 0.95, as TrackEval reports it.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from spacetrack.tracking.iou_matching import iou_matrix

try:
    from trackeval.metrics import HOTA
except ImportError as err:  # a core dependency, installed without its OpenCV by `make install`
    raise ImportError(
        "TrackEval (the HOTA metric) is not installed: `make install` installs it "
        "(pip install --no-deps trackeval==1.3.0)"
    ) from err

# Our metric names -> TrackEval's HOTA fields (arrays over alpha).
FIELDS = {"hota": "HOTA", "deta": "DetA", "assa": "AssA", "loca": "LocA"}


def _dense_ids(ids: np.ndarray) -> np.ndarray:
    """Track ids renumbered 0..K-1 (TrackEval indexes its count matrices by id)."""
    return np.unique(ids.astype(np.int64), return_inverse=True)[1].reshape(-1)


def sequence_data(gt: np.ndarray, hyp: np.ndarray, keep: np.ndarray) -> dict:
    """TrackEval's per-sequence input from ground truth `gt` and results `hyp` (MOT arrays).

    keep: (len(hyp),) bool, the hypotheses to score (`mot.accumulate`'s rule drops the others).
    `gt` must hold only the rows to score.
    """
    hyp = hyp[keep]
    gt_ids, hyp_ids = _dense_ids(gt[:, 1]), _dense_ids(hyp[:, 1])
    gt_frames, hyp_frames = gt[:, 0].astype(int), hyp[:, 0].astype(int)
    data: dict = {"gt_ids": [], "tracker_ids": [], "similarity_scores": []}
    for frame in np.union1d(gt_frames, hyp_frames):
        g, h = gt_frames == frame, hyp_frames == frame
        data["gt_ids"].append(gt_ids[g])
        data["tracker_ids"].append(hyp_ids[h])
        data["similarity_scores"].append(iou_matrix(gt[g, 2:6], hyp[h, 2:6]))
    data |= {
        "num_gt_dets": len(gt),
        "num_tracker_dets": len(hyp),
        "num_gt_ids": len(np.unique(gt_ids)),
        "num_tracker_ids": len(np.unique(hyp_ids)),
        "num_timesteps": len(data["gt_ids"]),
    }
    return data


def _means(res: Mapping[str, np.ndarray]) -> dict[str, float]:
    return {key: float(np.mean(res[field])) for key, field in FIELDS.items()}


def hota_scores(data: Mapping[str, dict], overall: str) -> dict[str, dict[str, float]]:
    """{name: {hota, deta, assa, loca}} for each `sequence_data` dict, plus `overall` (TrackEval's
    combination: detections pooled, AssA and LocA weighted by each sequence's true positives)."""
    metric = HOTA()
    raw = {name: metric.eval_sequence(d) for name, d in data.items()}
    out = {name: _means(res) for name, res in raw.items()}
    if raw:
        out[overall] = _means(metric.combine_sequences(raw))
    return out
