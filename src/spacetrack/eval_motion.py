"""Score the motion detectors against rendered ground truth, per scenario, and draw their masks.

python -m spacetrack.eval_motion dataset=data/motion_eval [scenarios=[dim,slew]] [logger=none]

Every method of `cfg.methods` runs over every selected sequence; all are scored on the same frames (from
`warmup` to the last frame every method has a mask for). Every method runs as configured (our methods
with `compensate: auto`: global motion compensation once the scene is found to move); scenarios in
`compensate_scenarios` are scored twice more, as `<scenario>_off` and `<scenario>_gmc`, with compensation
switched off and on from the first frame for the methods that have it. The overall score pools the
rows as configured.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.config import resolved_dict
from spacetrack.data.layout import load_manifest
from spacetrack.io import atomic_write_text
from spacetrack.mlflow_log import log_artifact_file, log_metrics_step, start_run
from spacetrack.motion.scoring import OVERALL, json_safe, markdown, score_rows, scoring_rows

log = logging.getLogger(__name__)


def run(cfg: DictConfig) -> dict[str, float]:
    """Score every method per scenario; write accuracy.json, accuracy.md and sheet_<scenario>.jpg.

    Returns `<scenario>.<method>.<metric>` for every row and `overall.<method>.<metric>` pooled over the
    rows scored as configured (not the `_off` and `_gmc` ones).
    """
    root, out_dir = Path(cfg.dataset), Path(cfg.output_dir)
    if not out_dir.is_dir():
        raise FileNotFoundError(f"output_dir {out_dir} does not exist")
    rows = scoring_rows(cfg, root)
    both = [label.removesuffix("_off") for label, _, on in rows if on is False]  # scored off and on too
    with start_run(cfg, run_name=root.name):
        results = score_rows(cfg, root, rows, out_dir)
        metrics = {
            f"{label}.{m}.{k}": v
            for label, row in results.items()
            for m, s in row.items()
            for k, v in s.items()
        }
        record = {
            "dataset": str(root),
            "content_hash": load_manifest(root).get("content_hash"),
            "also_scored_off_and_on": both,
            # where this machine keeps its MLflow store says nothing about the result
            "config": {k: v for k, v in resolved_dict(cfg).items() if k != "logger"},
            "results": results,
        }
        atomic_write_text(out_dir / "accuracy.json", json.dumps(json_safe(record), indent=2) + "\n")
        atomic_write_text(out_dir / "accuracy.md", markdown(results, list(cfg.methods)))
        log_metrics_step(metrics, step=0)
        for path in [
            out_dir / "accuracy.json",
            out_dir / "accuracy.md",
            *sorted(out_dir.glob("sheet_*.jpg")),
        ]:
            log_artifact_file(path)
    log.info("overall pixel F1: %s", {m: round(s["pixel_f1"], 3) for m, s in results[OVERALL].items()})
    return metrics


@cli.entry_point("eval_motion", files="output_dir")
def main(cfg: DictConfig) -> dict[str, float]:
    metrics = run(cfg)
    return {
        f"{k.split('.')[1]} pixel_f1": v
        for k, v in metrics.items()
        if k.startswith("overall.") and k.endswith(".pixel_f1")
    }


if __name__ == "__main__":
    main()
