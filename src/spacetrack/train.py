"""Train the YOLOv5s(+GAM) detector on eight folds and validate on the ninth: `python -m spacetrack.train fold=3`.

The run folder holds `weights/best.pt`, `weights/last.pt` and `plots/` (PR curve and a grid of
validation predictions of the best epoch); the same go to MLflow with per-epoch losses and metrics.
`torchrun --nproc_per_node=N -m spacetrack.train fold=3` (`make train FOLD=3 GPUS=N`) trains one model on N
GPUs with DistributedDataParallel; rank 0 writes the folder and the MLflow run (docs/scaling-out.md).
"""

from __future__ import annotations

from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.engine.training import train_fold

fit = train_fold  # one fold with its checkpoints and MLflow run id, as pretrain and the studies use it


def run(cfg: DictConfig) -> dict[str, float]:
    """Best-epoch metrics of fold `cfg.fold` (a child of run `cfg.cv_parent_run_id` when one is set)."""
    return train_fold(cfg)["metrics"]


@cli.entry_point("train", metric="fitness", files="output_dir")
def main(cfg: DictConfig) -> float:
    return run(cfg)["fitness"]


if __name__ == "__main__":
    main()
