"""A Hydra callback that makes a multirun over folds one MLflow cross-validation.

On multirun start it opens a parent run and exports its id as `SPACETRACK_CV_PARENT_RUN_ID` (the
train config reads it into `cv_parent_run_id`, so every fold's run becomes a child; environment
variables also reach jobs that a cluster launcher starts elsewhere). On multirun end it logs the mean
and standard deviation of `metrics` over the finished folds on the parent and closes it.
"""

from __future__ import annotations

import os
from contextlib import ExitStack
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from spacetrack.mlflow_log import cv_parent_summary, start_run

PARENT_ENV = "SPACETRACK_CV_PARENT_RUN_ID"


class CrossValidationCallback(Callback):
    def __init__(self, *, metrics: list[str]) -> None:
        self.metrics = list(metrics)
        self._stack = ExitStack()
        self._parent_id: str | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        if not config.logger.enabled:
            return
        # Only what the parent needs: the full config holds per-job interpolations not yet resolvable.
        summary = OmegaConf.create(
            {
                "task_name": config.task_name,
                "logger": OmegaConf.to_container(config.logger, resolve=True),
                "sweep": list(config.hydra.overrides.task),
            }
        )
        run = self._stack.enter_context(
            start_run(summary, run_name="cross-validation", tags={"cv": "parent"})
        )
        self._parent_id = run.info.run_id
        os.environ[PARENT_ENV] = self._parent_id

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        if self._parent_id is None:
            return
        try:
            cv_parent_summary(self._parent_id, self.metrics)
        finally:
            os.environ.pop(PARENT_ENV, None)
            self._stack.close()
