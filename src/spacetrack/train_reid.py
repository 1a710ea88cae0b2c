"""Train the Table 1 re-ID network on the rendered identities, one fold or the whole cross-validation.

python -m spacetrack.train_reid fold=3                     # train on folds != 3, evaluate on fold 3
python -m spacetrack.train_reid cv=true                    # every fold: a parent run, one child per fold
python -m spacetrack.train_reid train_reid=smoke data=smoke logger=none
"""

from __future__ import annotations

import hydra
from omegaconf import DictConfig

from spacetrack.config import CONF_DIR
from spacetrack.data.layout import load_manifest
from spacetrack.mlflow_log import cv_parent_summary, start_run
from spacetrack.reid.pipeline import train_fold

CV_METRICS = ("rank1", "mAP", "pair_same_below_0.1", "pair_same_below_0.2", "gallery_same_below_0.1")


def run(cfg: DictConfig) -> dict[str, float]:
    """Held-out metrics of fold `cfg.fold`, or with `cfg.cv` their mean and std over every fold."""
    if not cfg.cv:
        return train_fold(cfg, int(cfg.fold))
    num_folds = int(load_manifest(cfg.dataset)["num_folds"])
    with start_run(cfg, run_name="cv") as parent:
        folds = [
            train_fold(cfg, k, parent_run_id=parent.info.run_id if parent else None) for k in range(num_folds)
        ]
        if parent is not None:
            return cv_parent_summary(parent.info.run_id, CV_METRICS)
    return {f"{m}_mean": sum(f[m] for f in folds) / len(folds) for m in CV_METRICS}


@hydra.main(version_base=None, config_path=str(CONF_DIR), config_name="train_reid")
def main(cfg: DictConfig) -> float:
    return run(cfg)["rank1" if not cfg.cv else "rank1_mean"]


if __name__ == "__main__":
    main()
