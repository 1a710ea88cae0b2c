"""A Hydra callback that makes a multirun over folds one MLflow cross-validation.

The parent run's id reaches the jobs as `SPACETRACK_CV_PARENT_RUN_ID` (the train configs read it into
`cv_parent_run_id`, so every fold's run becomes a child). At the end it logs the mean and standard
deviation of `metrics` over the finished folds on the parent (see `spacetrack.multirun`).
"""

from __future__ import annotations

from spacetrack.mlflow_log import cv_parent_summary
from spacetrack.multirun import MultirunParent

PARENT_ENV = "SPACETRACK_CV_PARENT_RUN_ID"


class CrossValidationCallback(MultirunParent):
    env_var = PARENT_ENV
    run_name = "cross-validation"
    tags = {"cv": "parent"}

    def __init__(self, *, metrics: list[str]) -> None:
        super().__init__()
        self.metrics = list(metrics)

    def finish(self, *, failed: bool) -> None:
        if self.parent_id is None:
            return
        try:
            cv_parent_summary(self.parent_id, self.metrics)
        except ValueError:
            # after a failed fold there may be no finished fold to summarise; the parent is marked FAILED
            if not failed:
                raise
