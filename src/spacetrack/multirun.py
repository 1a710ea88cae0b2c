"""MLflow parent runs for Hydra multiruns: a cross-validation over folds, a sweep over settings.

`MultirunParent` opens a parent run when the multirun starts and exports its id in an environment
variable (the job configs read it, so each job's run becomes a child; variables also reach jobs that a
cluster launcher starts elsewhere), and the swept keys in `SPACETRACK_SWEPT_KEYS` (each child is named
after its values: `max_cosine_distance=0.2 max_iou_distance=0.5`). The parent's description says what
is swept over which folds. A bar counts the finished jobs. It closes the parent when the multirun ends,
and also at exit when a job failed — Hydra skips `on_multirun_end` then — marking it FAILED, so no
parent is left open; then it prints one summary line with the parent's URL. Subclasses summarise the
finished jobs onto the parent in `finish` and say what the line shows in `headline`.
"""

from __future__ import annotations

import atexit
import math
import os
from contextlib import ExitStack
from typing import Any

import mlflow
from hydra.core.override_parser.overrides_parser import OverridesParser
from hydra.core.utils import JobReturn
from hydra.experimental.callback import Callback
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from spacetrack import cli, mlflow_ui
from spacetrack.mlflow_log import NOTE_TAG, SWEPT_ENV, start_run


def sweep_values(config: DictConfig) -> dict[str, list[str] | None]:
    """{key: its values} of every swept key of the multirun (command line and `hydra.sweeper.params`),
    None for a search space (an interval, or a sweeper's own syntax) rather than a list of values."""
    given = list(config.hydra.overrides.task)
    params = OmegaConf.select(config, "hydra.sweeper.params") or {}
    given += [f"{k}={v}" for k, v in params.items()]
    swept: dict[str, list[str] | None] = {}
    for override in OverridesParser.create().parse_overrides(given):
        if override.is_sweep_override():
            key = override.key_or_group
            values = None if override.is_interval_sweep() else list(override.sweep_string_iterator())
            swept[key] = values
    return swept


def number_of_jobs(config: DictConfig, swept: dict[str, list[str] | None]) -> int | None:
    """Jobs the multirun will launch: the grid's size, or the sweeper's `n_trials`; None if unknown."""
    trials = OmegaConf.select(config, "hydra.sweeper.n_trials")
    if trials is not None:
        return int(trials)
    sizes = [len(v) for v in swept.values() if v is not None]
    return math.prod(sizes) if sizes and len(sizes) == len(swept) else None


def describe(config: DictConfig, swept: dict[str, list[str] | None], jobs: int | None) -> str:
    """What the multirun varies, on which data and folds, as one markdown paragraph."""
    varied = [
        f"`{k}` over {', '.join(v) if v else 'a search space'}" for k, v in swept.items() if k != "fold"
    ]
    where = f"folds {', '.join(swept['fold'] or [])}" if "fold" in swept else None
    if where is None and OmegaConf.select(config, "fold") is not None:
        where = f"fold {config.fold}"
    if OmegaConf.select(config, "sequence") is not None:
        where = f"sequence {config.sequence}" + (f" ({where})" if where else "")
    data = OmegaConf.select(config, "data.name")
    text = f"`{config.task_name}` multirun" + (f" of {jobs} jobs" if jobs else "")
    text += ": " + ("; ".join(varied) if varied else "the folds")
    text += (f", on {where}" if where else "") + (f" of dataset {data}" if data else "") + "."
    return text


class MultirunParent(Callback):
    env_var = "SPACETRACK_PARENT_RUN_ID"
    run_name = "multirun"
    tags: dict[str, str] = {}

    def __init__(self) -> None:
        self._stack = ExitStack()
        self.parent_id: str | None = None
        self.swept: dict[str, list[str] | None] = {}
        self.description = ""
        self._task = "multirun"
        self._folder = "."
        self._bar: tqdm | None = None

    def on_multirun_start(self, config: DictConfig, **kwargs: Any) -> None:
        atexit.register(self._end, failed=True)
        self._task = str(config.task_name)
        self._folder = str(OmegaConf.select(config, "hydra.sweep.dir", default="."))
        self.swept = sweep_values(config)
        jobs = number_of_jobs(config, self.swept)
        self.description = describe(config, self.swept, jobs)
        self._bar = tqdm(total=jobs, unit="job", desc=self._task, dynamic_ncols=True)
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
        tags = {**self.tags, "swept": ",".join(self.swept), NOTE_TAG: self.description}
        run = self._stack.enter_context(start_run(summary, run_name=self.run_name, tags=tags))
        self.parent_id = run.info.run_id
        os.environ[self.env_var] = self.parent_id
        os.environ[SWEPT_ENV] = ",".join(self.swept)

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        if self._bar is not None:
            self._bar.update(1)

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        self._end(failed=False)

    def start(self, config: DictConfig) -> None:
        """Called first when the multirun starts (whether or not logging is on)."""

    def finish(self, *, failed: bool) -> None:
        """Summarise the finished jobs (onto `self.parent_id` when logging is on); `failed` if a job failed."""

    def headline(self) -> str:
        """The metrics of the summary line: by default the means and spreads logged on the parent."""
        if self.parent_id is None:
            return ""
        metrics = mlflow.MlflowClient().get_run(self.parent_id).data.metrics
        return ", ".join(
            f"{k} {v:.4g}" + (f" ± {metrics[k[:-5] + '_std']:.4g}" if k[:-5] + "_std" in metrics else "")
            for k, v in sorted(metrics.items())
            if k.endswith("_mean")
        )

    def parent_url(self) -> str | None:
        if self.parent_id is None:
            return None
        run = mlflow.MlflowClient().get_run(self.parent_id)
        uri = mlflow.get_tracking_uri()
        return mlflow_ui.run_url(run.info.experiment_id, self.parent_id, uri) + mlflow_ui.served_note(uri)

    def _end(self, *, failed: bool) -> None:
        atexit.unregister(self._end)
        if self._bar is not None:
            self._bar.close()
            self._bar = None
        try:
            self.finish(failed=failed)
            folder = cli.shown_path(self._folder)
            cli.print_summary(self._task, self.headline(), folder, self.parent_url() or cli.NOT_LOGGED)
        finally:
            os.environ.pop(self.env_var, None)
            os.environ.pop(SWEPT_ENV, None)
            if failed and self.parent_id is not None:
                mlflow.end_run("FAILED")
            self._stack.close()
            self.parent_id = None
