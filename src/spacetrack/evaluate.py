"""Score a MOT results file against a ground-truth file: `python -m spacetrack.evaluate results=R gt=G`."""

from __future__ import annotations

import json
from pathlib import Path

from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.data.layout import read_mot
from spacetrack.evaluation import OVERALL, evaluate
from spacetrack.evaluation.table import format_table
from spacetrack.io import atomic_write_text
from spacetrack.mlflow_log import log_metrics_step, start_run


def run(cfg: DictConfig) -> dict[str, float]:
    """Print the metrics table, write JSON if `output_file` is set, return the overall metrics."""
    gt, results = read_mot(cfg.gt), read_mot(cfg.results)
    name = Path(cfg.results).stem
    with start_run(cfg, run_name=name):
        scores = evaluate(
            {name: (gt, results)}, iou_threshold=cfg.iou_threshold, min_visibility=cfg.min_visibility
        )
        print(format_table(scores), end="")
        if cfg.output_file:
            atomic_write_text(cfg.output_file, json.dumps(scores, indent=2) + "\n")
        log_metrics_step(scores[OVERALL], step=0)
    return scores[OVERALL]


@cli.entry_point("evaluate", files="output_file")
def main(cfg: DictConfig) -> dict[str, float]:
    scores = run(cfg)
    return {k: scores[k] for k in ("hota", "mota", "idf1", "idsw") if k in scores}


if __name__ == "__main__":
    main()
