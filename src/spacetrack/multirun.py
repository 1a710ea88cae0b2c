"""MLflow parent runs for Hydra multiruns: a cross-validation over folds, a sweep over settings.

`MultirunParent` opens a parent run when the multirun starts and exports its id in an environment
variable (the job configs read it, so each job's run becomes a child; variables also reach jobs that a
cluster launcher starts elsewhere). It closes the parent when the multirun ends, and also at exit when a
job failed — Hydra skips `on_multirun_end` then — marking it FAILED, so no parent is left open.
Subclasses summarise the finished jobs onto the parent in `finish`.
"""

from __future__ import annotations

import atexit
import os
from contextlib import ExitStack
from typing import Any

import mlflow
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf

from spacetrack.mlflow_log import start_run


class MultirunParent(Callback):
    env_var = "SPACETRACK_PARENT_RUN_ID"
    run_name = "multirun"
    tags: dict[str, str] = {}

    def __init__(self) -> None:
        self._stack = ExitStack()
        self.parent_id: str | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        atexit.register(self._end, failed=True)
        self.start(config)
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
        run = self._stack.enter_context(start_run(summary, run_name=self.run_name, tags=self.tags))
        self.parent_id = run.info.run_id
        os.environ[self.env_var] = self.parent_id

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        self._end(failed=False)

    def start(self, config: DictConfig) -> None:
        """Called first when the multirun starts (whether or not logging is on)."""

    def finish(self, *, failed: bool) -> None:
        """Summarise the finished jobs (onto `self.parent_id` when logging is on); `failed` if a job failed."""

    def _end(self, *, failed: bool) -> None:
        atexit.unregister(self._end)
        try:
            self.finish(failed=failed)
        finally:
            os.environ.pop(self.env_var, None)
            if failed and self.parent_id is not None:
                mlflow.end_run("FAILED")
            self._stack.close()
            self.parent_id = None
