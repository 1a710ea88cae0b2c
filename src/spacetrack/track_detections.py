"""Run the tracker alone on a detection file and write MOT results (no image, network or GPU needed).

python -m spacetrack.track_detections detections=IN.npy output_file=OUT.txt tracker=deepsort_paper
"""

from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.data.layout import read_mot
from spacetrack.evaluation import OVERALL, evaluate
from spacetrack.mlflow_log import log_artifact_file, log_metrics_step, start_run
from spacetrack.tracking import track_sequence
from spacetrack.tracking.io import DETECTION_COLUMNS, DetectionFileError, load_detections, write_mot_results

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict[str, float]:
    """Track `cfg.detections` with `cfg.tracker`, write `cfg.output_file`; score against `cfg.gt` if given.

    Returns frame, detection and track counts, the tracker's milliseconds per frame and, with `gt`,
    the overall metrics of `spacetrack.evaluation.summarize`.
    """
    output = Path(cfg.output_file)
    if not output.parent.is_dir():
        raise FileNotFoundError(f"output folder {output.parent} does not exist (writing {output.name})")
    dets = load_detections(cfg.detections)
    if dets.shape[1] == len(DETECTION_COLUMNS) and cfg.tracker.get("max_cosine_distance") is not None:
        raise DetectionFileError(
            f"{cfg.detections}: no appearance features (10 columns), but the tracker matches by "
            "appearance; use tracker=sort (or tracker.max_cosine_distance=null) for boxes alone"
        )
    gt = read_mot(cfg.gt) if cfg.gt else None
    tracker = instantiate(cfg.tracker)
    with start_run(cfg, run_name=Path(cfg.detections).stem):
        start = time.perf_counter()
        rows = track_sequence(tracker, dets)
        elapsed = time.perf_counter() - start
        write_mot_results(output, rows)
        num_frames = int(dets[-1, 0] - dets[0, 0]) + 1
        metrics = {
            "num_frames": float(num_frames),
            "num_detections": float(len(dets)),
            "num_tracks": float(len(np.unique(rows[:, 1]))),
            "ms_per_frame": 1e3 * elapsed / num_frames,
        }
        if gt is not None:
            scores = evaluate(
                {output.stem: (gt, rows_as_mot(rows))},
                iou_threshold=cfg.iou_threshold,
                min_visibility=cfg.min_visibility,
            )
            metrics.update(scores[OVERALL])
        log_metrics_step(metrics, step=0)
        log_artifact_file(output)
    log.info("%s -> %s: %s", cfg.detections, output, {k: round(v, 4) for k, v in metrics.items()})
    return metrics


def rows_as_mot(rows: np.ndarray) -> np.ndarray:
    """Tracker rows (frame, id, x, y, w, h) as (N, 9) MOT rows with conf 1, class -1, visibility -1."""
    tail = np.tile([1.0, -1.0, -1.0], (len(rows), 1))
    return np.hstack([np.asarray(rows, dtype=float).reshape(-1, 6), tail])


@cli.entry_point("track_detections", files="output_file")
def main(cfg: DictConfig) -> dict[str, float]:
    metrics = run(cfg)
    return {k: metrics[k] for k in ("mota", "idf1", "num_tracks", "ms_per_frame") if k in metrics}


if __name__ == "__main__":
    main()
