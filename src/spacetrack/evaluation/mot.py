"""CLEAR-MOT and identity metrics (MOTA, MOTP, IDF1, IDSW, FP, FN, MT, ML) at an IoU threshold, and HOTA.

Pure functions of MOT arrays (N, 9) `frame,id,x,y,w,h,conf,class,visibility` (boxes `tlwh`, pixels);
motmetrics does the bookkeeping, we compute the IoU distances (its own helper needs NumPy < 2).
Ground-truth rows with conf 0 (fully hidden targets) or a known visibility below `min_visibility` are
ignored as MOTChallenge does: they are neither misses nor matches, and a hypothesis that the frame's
optimal assignment pairs with one of them is dropped rather than counted as a false positive.
HOTA, DetA, AssA and LocA come from TrackEval (`evaluation.hota`) on the same rows.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path

import motmetrics as mm
import numpy as np
from scipy.optimize import linear_sum_assignment

from spacetrack.data.layout import CLASS
from spacetrack.evaluation.hota import hota_scores, sequence_data
from spacetrack.tracking.iou_matching import iou_matrix

OVERALL = "OVERALL"
_MM_METRICS = {
    "mota": "mota",
    "motp": "motp",
    "idf1": "idf1",
    "idp": "idp",
    "idr": "idr",
    "idsw": "num_switches",
    "fp": "num_false_positives",
    "fn": "num_misses",
    "mt": "mostly_tracked",
    "pt": "partially_tracked",
    "ml": "mostly_lost",
    "frag": "num_fragmentations",
    "precision": "precision",
    "recall": "recall",
    "num_gt_ids": "num_unique_objects",
    "num_frames": "num_frames",
}


@contextmanager
def _quiet_motmetrics() -> Iterator[None]:
    """Drop motmetrics' timing messages, which it sends to the root logger at INFO level."""
    package = str(Path(mm.__file__).parent)

    def quiet(record: logging.LogRecord) -> bool:
        return not record.pathname.startswith(package)

    root = logging.getLogger()
    root.addFilter(quiet)
    try:
        yield
    finally:
        root.removeFilter(quiet)


def iou_distance(gt_tlwh: np.ndarray, hyp_tlwh: np.ndarray, iou_threshold: float = 0.5) -> np.ndarray:
    """(N, M) matrix 1 - IoU, NaN (never a match) where IoU < `iou_threshold`."""
    distance = 1.0 - iou_matrix(gt_tlwh, hyp_tlwh)
    return np.where(distance > 1.0 - iou_threshold, np.nan, distance)


def ignored_rows(gt: np.ndarray, min_visibility: float = 0.0) -> np.ndarray:
    """Boolean mask of ground-truth rows to ignore: conf 0, or visibility known (>= 0) and too low."""
    visibility = gt[:, 8]
    return (gt[:, 6] == 0) | ((visibility >= 0) & (visibility < min_visibility))


def _hypotheses_on_ignored(
    gt_tlwh: np.ndarray, ignored: np.ndarray, hyp_tlwh: np.ndarray, iou_threshold: float
) -> np.ndarray:
    """Mask of hypotheses that the optimal assignment to all ground truth pairs with an ignored row."""
    out = np.zeros(len(hyp_tlwh), bool)
    if not ignored.any() or not len(hyp_tlwh):
        return out
    distance = iou_distance(gt_tlwh, hyp_tlwh, iou_threshold)
    rows, cols = linear_sum_assignment(np.where(np.isnan(distance), 2.0, distance))
    valid = ~np.isnan(distance[rows, cols])
    out[cols[valid & ignored[rows]]] = True
    return out


def scored_rows(
    gt: np.ndarray, hyp: np.ndarray, *, iou_threshold: float = 0.5, min_visibility: float = 0.0
) -> tuple[np.ndarray, np.ndarray]:
    """(gt mask, hyp mask) of the rows that count: ground truth less `ignored_rows`, results less the
    hypotheses each frame's optimal assignment pairs with an ignored row."""
    ignored = ignored_rows(gt, min_visibility) if gt.shape[1] > 8 else np.zeros(len(gt), bool)
    dropped = np.zeros(len(hyp), bool)
    gt_frames, hyp_frames = gt[:, 0].astype(int), hyp[:, 0].astype(int)
    for frame in np.unique(gt_frames[ignored]):
        g, h = gt_frames == frame, hyp_frames == frame
        dropped[h] = _hypotheses_on_ignored(gt[g, 2:6], ignored[g], hyp[h, 2:6], iou_threshold)
    return ~ignored, ~dropped


def accumulate(
    gt: np.ndarray, hyp: np.ndarray, *, iou_threshold: float = 0.5, min_visibility: float = 0.0
) -> mm.MOTAccumulator:
    """Frame-by-frame matching of results `hyp` against ground truth `gt` (both (N, >=6) MOT arrays)."""
    acc = mm.MOTAccumulator(auto_id=False)
    gt_keep, hyp_keep = scored_rows(gt, hyp, iou_threshold=iou_threshold, min_visibility=min_visibility)
    gt_frames, hyp_frames = gt[:, 0].astype(int), hyp[:, 0].astype(int)
    for frame in np.union1d(gt_frames, hyp_frames):
        g, h = gt[(gt_frames == frame) & gt_keep], hyp[(hyp_frames == frame) & hyp_keep]
        acc.update(
            g[:, 1].astype(int),
            h[:, 1].astype(int),
            iou_distance(g[:, 2:6], h[:, 2:6], iou_threshold),
            frameid=frame,
        )
    return acc


def summarize(accumulators: Mapping[str, mm.MOTAccumulator]) -> dict[str, dict[str, float]]:
    """Metrics per sequence name plus `OVERALL` (all sequences pooled), as plain dicts of floats.

    MOTA, IDF1, precision and recall are fractions; MOTP is the mean IoU of matched pairs (the
    MOTChallenge convention; motmetrics itself reports 1 - that); the rest are counts.
    """
    names = list(accumulators)
    host = mm.metrics.create()
    with _quiet_motmetrics():
        frame = host.compute_many(
            [accumulators[n] for n in names],
            metrics=[*_MM_METRICS.values(), "num_detections"],
            names=names,
            generate_overall=True,
        )
    frame = frame.rename(index={"OVERALL": OVERALL})
    out: dict[str, dict[str, float]] = {}
    for name, row in frame.iterrows():
        metrics = {key: float(row[mm_key]) for key, mm_key in _MM_METRICS.items()}
        metrics["motp"] = 1.0 - metrics["motp"]
        out[str(name)] = metrics
    # motmetrics pools MOTP as sum(motp * matches) / matches, and a sequence without a match has motp NaN,
    # which turns the pooled value NaN too (0 * NaN); such a sequence adds no match, so leave it out.
    matched = [
        (out[n]["motp"], frame.loc[n, "num_detections"]) for n in names if frame.loc[n, "num_detections"] > 0
    ]
    if matched:
        out[OVERALL]["motp"] = float(sum(m * k for m, k in matched) / sum(k for _, k in matched))
    return out


def evaluate(
    sequences: Mapping[str, tuple[np.ndarray, np.ndarray]],
    *,
    iou_threshold: float = 0.5,
    min_visibility: float = 0.0,
    accumulators: dict[str, mm.MOTAccumulator] | None = None,
) -> dict[str, dict[str, float]]:
    """`summarize` of {name: (gt, hyp)} MOT arrays plus HOTA, DetA, AssA and LocA (`hota`, fractions);
    see `scored_rows` for which rows count. Each sequence's matching is added to `accumulators` when
    given (for `named_matches`, which then need not match again)."""
    accs = {} if accumulators is None else accumulators
    data = {}
    for name, (gt, hyp) in sequences.items():
        accs[name] = accumulate(gt, hyp, iou_threshold=iou_threshold, min_visibility=min_visibility)
        gt_keep, hyp_keep = scored_rows(gt, hyp, iou_threshold=iou_threshold, min_visibility=min_visibility)
        data[name] = sequence_data(gt[gt_keep], hyp, hyp_keep)
    out = summarize(accs)
    for name, scores in hota_scores(data, OVERALL).items():
        out[name] |= scores
    return out


def named_matches(
    gt: np.ndarray,
    hyp: np.ndarray,
    hyp_classes: np.ndarray,
    *,
    iou_threshold: float = 0.5,
    min_visibility: float = 0.0,
    matching: mm.MOTAccumulator | None = None,
) -> np.ndarray:
    """(M, 3) int rows, one per result box matched to a target by `accumulate`: the target's class
    (`gt` column CLASS), and the two names of `hyp_classes` (N, k >= 1 columns aligned with `hyp`'s rows,
    e.g. the class of the frame's own detection and the track's voted class; -1: unnamed). `matching`:
    the accumulator `evaluate` already made of this (gt, hyp) pair, matched again when absent."""
    hyp_classes = np.asarray(hyp_classes, dtype=int).reshape(len(hyp), -1)
    if matching is None:
        matching = accumulate(gt, hyp, iou_threshold=iou_threshold, min_visibility=min_visibility)
    events = matching.mot_events
    matched = events[events["Type"] == "MATCH"]
    gt_class = {(int(f), int(k)): int(c) for f, k, c in gt[:, [0, 1, CLASS]]}
    hyp_row = {(int(f), int(k)): i for i, (f, k) in enumerate(hyp[:, :2])}
    rows = [
        (gt_class[frame, int(o)], *hyp_classes[hyp_row[frame, int(h)]])
        for (frame, _), o, h in zip(matched.index, matched["OId"], matched["HId"], strict=True)
    ]
    return np.array(rows, dtype=int).reshape(-1, 1 + hyp_classes.shape[1])


def class_accuracy(named: np.ndarray) -> dict[str, float]:
    """From `named_matches` rows (target class, the frame's own detection class, the track's voted class):
    `class_accuracy`, the share of matched boxes whose track's vote names the target right;
    `class_accuracy_frame`, the share of matched boxes on a frame with their own detection that it names
    right (the detector frame by frame); `class_matches`, how many matched boxes (NaN shares without)."""
    named = np.asarray(named, dtype=int).reshape(-1, 3)
    own = named[named[:, 1] >= 0]

    def share(hit: np.ndarray) -> float:
        return float(hit.mean()) if len(hit) else float("nan")

    return {
        "class_accuracy": share(named[:, 2] == named[:, 0]),
        "class_accuracy_frame": share(own[:, 1] == own[:, 0]),
        "class_matches": float(len(named)),
    }
