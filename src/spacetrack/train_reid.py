"""Train the Table 1 re-ID network on the rendered identities and evaluate it on a held-out fold.

python -m spacetrack.train_reid fold=3                        # train on folds != 3, evaluate on fold 3
python -m spacetrack.train_reid -m fold=0,1,2,3,4,5,6,7,8     # cross-validation: one MLflow parent run
python -m spacetrack.train_reid train_reid=smoke data=smoke logger=none
torchrun --nproc_per_node=4 -m spacetrack.train_reid fold=3  # one network on 4 GPUs (make train-reid GPUS=4)
"""

from __future__ import annotations

from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.reid.training import train_fold


def run(cfg: DictConfig) -> dict[str, float]:
    """Held-out metrics of fold `cfg.fold` (a child of run `cfg.cv_parent_run_id` when one is set)."""
    return train_fold(cfg, int(cfg.fold), parent_run_id=cfg.cv_parent_run_id)


@cli.entry_point("train_reid", metric="rank1", files="output_dir")
def main(cfg: DictConfig) -> float:
    return run(cfg)["rank1"]


if __name__ == "__main__":
    main()
