"""MLflow run logging shared by every entry point.

`start_run(cfg)` opens a run in experiment `cfg.logger.experiment` on `cfg.logger.tracking_uri` and logs
what makes the run reproducible: the resolved Hydra config (flattened params and a `config.yaml`
artifact) and the git commit. The helpers below it are no-ops when no run is active, so a stage calls
them unconditionally and `logger=none` silences everything.

The default store is `sqlite:///mlflow.db` in the repository root; a relative sqlite path is anchored at
the repository root, and artifacts of a sqlite store go to `mlartifacts/` beside the database, so runs
and their files land in one place whatever the working directory.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import tempfile
import threading
from collections.abc import Iterator, Mapping, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any
from urllib.parse import urlparse
from urllib.request import url2pathname

import mlflow
import numpy as np
from hydra.core.hydra_config import HydraConfig
from hydra.core.override_parser.overrides_parser import OverridesParser
from mlflow.entities import Run, RunStatus
from mlflow.exceptions import MlflowException
from mlflow.utils.validation import MAX_PARAM_VAL_LENGTH
from omegaconf import DictConfig, OmegaConf

from spacetrack.config import REPO_ROOT, resolved_dict

DEFAULT_TRACKING_URI = "sqlite:///mlflow.db"
_SQLITE = "sqlite:///"
PARENT_RUN_TAG = "mlflow.parentRunId"
GIT_COMMIT_TAG = "mlflow.source.git.commit"
NOTE_TAG = "mlflow.note.content"  # the run's description in the UI (markdown)
SWEPT_ENV = "SPACETRACK_SWEPT_KEYS"  # the keys a multirun sweeps, comma-separated (spacetrack.multirun)
# Tells the MLflow 3 UI these are model-training experiments (runs table, metric charts), not GenAI ones.
EXPERIMENT_TAGS = {"mlflow.experimentKind": "custom_model_development"}


def tracking_uri(uri: str | None = None) -> str:
    """`uri`, else `$MLFLOW_TRACKING_URI`, else `sqlite:///<repo root>/mlflow.db`.

    A relative sqlite path (`sqlite:///mlflow.db`) is made absolute under the repository root.
    """
    uri = uri or os.environ.get("MLFLOW_TRACKING_URI") or DEFAULT_TRACKING_URI
    if uri.startswith(_SQLITE):
        db = Path(uri[len(_SQLITE) :])
        if not db.is_absolute():
            return _SQLITE + str(REPO_ROOT / db)
    return uri


def flatten_params(tree: Mapping[str, Any], prefix: str = "") -> dict[str, str]:
    """Nested mapping -> {"dotted.key": str(value)}; values cut to MLflow's parameter length limit."""
    flat: dict[str, str] = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping) and value:
            flat.update(flatten_params(value, prefix=f"{name}."))
        else:
            flat[name] = str(value)[:MAX_PARAM_VAL_LENGTH]
    return flat


def sweep_point(cfg: DictConfig) -> dict[str, str]:
    """{key: this job's value} of the keys the running multirun sweeps ({} outside a multirun's job): the
    job's overrides as given (`model=yolov5s_gam` for a config group), else the config's values."""
    keys = [k for k in os.environ.get(SWEPT_ENV, "").split(",") if k]
    if not keys:
        return {}
    given = {}
    if HydraConfig.initialized():
        for override in OverridesParser.create().parse_overrides(list(HydraConfig.get().overrides.task)):
            given[override.key_or_group] = override.get_value_element_as_str()
    return {k: given[k] if k in given else str(OmegaConf.select(cfg, k)) for k in keys}


def point_name(point: Mapping[str, str]) -> str:
    """`max_cosine_distance=0.2 max_iou_distance=0.5`: the last part of each key, unless two share it."""
    short = {k: k.rsplit(".", 1)[-1] for k in point}
    if len(set(short.values())) < len(short):
        short = {k: k for k in point}
    return " ".join(f"{short[k]}={v}" for k, v in point.items())


def _experiment_id(name: str, uri: str) -> str:
    """Id of experiment `name`, created if missing (artifacts beside the database for sqlite stores)."""
    client = mlflow.MlflowClient()
    experiment = client.get_experiment_by_name(name)
    if experiment is not None:
        if experiment.lifecycle_stage != "active":
            raise ValueError(
                f"MLflow experiment {name!r} on {uri} is deleted; restore it or set logger.experiment"
            )
        return experiment.experiment_id
    location = None
    if uri.startswith(_SQLITE):
        slug = re.sub(r"[^A-Za-z0-9_.-]+", "_", name)
        location = (Path(uri[len(_SQLITE) :]).parent / "mlartifacts" / slug).as_uri()
    try:
        return client.create_experiment(name, artifact_location=location, tags=EXPERIMENT_TAGS)
    except MlflowException:
        # Another process (a parallel sweep job) created it between our lookup and create.
        experiment = client.get_experiment_by_name(name)
        if experiment is None:
            raise
        return experiment.experiment_id


def _git_tags() -> dict[str, str]:
    """Commit of the repository and whether the working tree differs from it (empty outside git)."""
    try:
        commit = subprocess.run(
            ["git", "-C", str(REPO_ROOT), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
        ).stdout.strip()
        status = subprocess.run(
            ["git", "-C", str(REPO_ROOT), "status", "--porcelain", "--untracked-files=no"],
            capture_output=True,
            text=True,
            check=True,
        ).stdout
    except (OSError, subprocess.CalledProcessError):
        return {}
    return {GIT_COMMIT_TAG: commit, "git_dirty": str(bool(status.strip())).lower()}


class Terminated(KeyboardInterrupt):
    """SIGTERM inside a run (a scheduler or a closing session stopping the job): ends the run KILLED."""


@contextmanager
def _sigterm_interrupts(seen: dict[str, bool]) -> Iterator[None]:
    """Turn SIGTERM into `Terminated` inside the block and note it in `seen["terminated"]` (main thread
    only; elsewhere nothing changes)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        seen["terminated"] = True
        raise Terminated(f"signal {signum}")

    previous = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


def find_run(run_id: str | None) -> mlflow.entities.Run | None:
    """The run `run_id` in the current tracking store, or None (no id, or a store that lacks it)."""
    if not run_id:
        return None
    try:
        return mlflow.MlflowClient().get_run(run_id)
    except MlflowException:
        return None


def finished_runs(
    experiment: str,
    *,
    tags: Mapping[str, str] | None = None,
    params: Mapping[str, str] | None = None,
    tracking_uri: str,
    max_results: int = 1000,
) -> list[mlflow.entities.Run]:
    """The FINISHED runs of `experiment` (none when there is no such experiment) that carry every tag in
    `tags` and parameter in `params` with those values, newest first."""
    client = mlflow.MlflowClient(tracking_uri=tracking_uri)
    found = client.get_experiment_by_name(experiment)
    if found is None:
        return []
    where = [f"tags.`{k}` = '{v}'" for k, v in (tags or {}).items()]
    where += [f"params.`{k}` = '{v}'" for k, v in (params or {}).items()]
    where.append("attributes.status = 'FINISHED'")
    return client.search_runs(
        [found.experiment_id],
        " and ".join(where),
        order_by=["attributes.start_time DESC"],
        max_results=max_results,
    )


@contextmanager
def start_run(
    cfg: DictConfig,
    *,
    run_name: str | None = None,
    parent_run_id: str | None = None,
    nested: bool = False,
    tags: Mapping[str, str] | None = None,
    continue_run_id: str | None = None,
) -> Iterator[mlflow.ActiveRun | None]:
    """Open an MLflow run for `cfg` and log its resolved config and git commit; yield the ActiveRun.

    Yields None and logs nothing when `cfg.logger.enabled` is false. With `parent_run_id` the run is a
    child of that run (a fold of a cross-validation); `nested=True` makes it a child of the active run.
    With `continue_run_id` (a resumed training) that run is reopened when this store has it: its params
    stay as first logged, the new config goes to `config_resume<n>.yaml` and tag `resumes` counts; when
    the store lacks it a new run starts. A child in a multirun's job is named after its swept values
    (`sweep_point`), which also come first among its params and as tags. The run ends FINISHED, FAILED
    when the block raises, or KILLED on Ctrl-C or SIGTERM.
    """
    if not cfg.logger.enabled:
        yield None
        return
    uri = tracking_uri(cfg.logger.tracking_uri)
    mlflow.set_tracking_uri(uri)
    experiment_id = _experiment_id(str(cfg.logger.experiment), uri)
    previous = find_run(continue_run_id)
    if previous is not None and previous.info.experiment_id != experiment_id:
        previous = None
    point = sweep_point(cfg) if parent_run_id is not None else {}
    if point:
        run_name = point_name(point)
        tags = {"swept": ",".join(point), **point, **(tags or {})}
    nested = nested or parent_run_id is not None
    if previous is not None:
        # MLflow refuses to reopen a run of another experiment than the process's active one
        mlflow.set_experiment(experiment_id=previous.info.experiment_id)
        run = mlflow.start_run(run_id=previous.info.run_id, nested=nested)
    else:
        run = mlflow.start_run(
            experiment_id=experiment_id,
            run_name=run_name,
            parent_run_id=parent_run_id,
            nested=nested,
            tags={**_git_tags(), **(tags or {})},
        )
    seen = {"terminated": False}
    try:
        with _sigterm_interrupts(seen):
            _log_config(cfg, previous, point)
            yield run
    except KeyboardInterrupt:
        mlflow.end_run(RunStatus.to_string(RunStatus.KILLED))
        raise
    except BaseException:
        # A stop signal can surface as another error (a data-loader worker killed by the same signal).
        mlflow.end_run(RunStatus.to_string(RunStatus.KILLED if seen["terminated"] else RunStatus.FAILED))
        raise
    mlflow.end_run(RunStatus.to_string(RunStatus.FINISHED))


def _log_config(cfg: DictConfig, previous: Run | None, point: Mapping[str, str]) -> None:
    """The active run's config: its params and `config.yaml` on a new run (the swept keys first), or on
    a reopened one (`previous`) the `resumes` count and `config_resume<n>.yaml`."""
    config_text = OmegaConf.to_yaml(cfg, resolve=True)
    if previous is not None:
        resumes = int(previous.data.tags.get("resumes", "0")) + 1
        mlflow.set_tags({**_git_tags(), "resumes": str(resumes)})
        mlflow.log_text(config_text, f"config_resume{resumes}.yaml")
        return
    params = flatten_params(resolved_dict(cfg))
    mlflow.log_params({**{k: params[k] for k in point if k in params}, **params})
    mlflow.log_text(config_text, "config.yaml")


def log_artifact_file(path: str | Path, artifact_path: str | None = None) -> None:
    """Copy the file at `path` into the active run's artifacts (under folder `artifact_path`).

    A missing file is an error even when no run is active, so turning the logger off hides no bug.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"cannot log artifact {path}: no such file")
    if mlflow.active_run() is not None:
        mlflow.log_artifact(str(path), artifact_path=artifact_path)


def artifact_file(run_id: str, artifact_path: str, *, tracking_uri: str) -> Path:
    """A local path of one file a run logged. With a local artifact store that is the stored file itself;
    otherwise it is downloaded once into `outputs/mlflow_artifacts/<run id>/` (atomically: a broken
    download leaves nothing there) and reused. MLflow's own download would copy it into a new temporary
    folder on every call, which is never removed."""
    client = mlflow.MlflowClient(tracking_uri=tracking_uri)
    root = client.get_run(run_id).info.artifact_uri
    parsed = urlparse(root)
    if parsed.scheme in ("", "file"):
        stored = Path(url2pathname(parsed.path)) / artifact_path
        if stored.is_file():
            return stored
    target = REPO_ROOT / "outputs" / "mlflow_artifacts" / run_id / artifact_path
    if not target.is_file():
        target.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=target.parent) as scratch:
            local = mlflow.artifacts.download_artifacts(
                run_id=run_id, artifact_path=artifact_path, dst_path=scratch, tracking_uri=tracking_uri
            )
            os.replace(local, target)
    return target


def log_metrics_step(metrics: Mapping[str, float], step: int) -> None:
    """Log `metrics` at `step` (epoch, frame or fold index) on the active run."""
    if mlflow.active_run() is not None:
        mlflow.log_metrics({name: float(value) for name, value in metrics.items()}, step=step)


def cv_parent_summary(parent_run_id: str, metric_names: Sequence[str]) -> dict[str, float]:
    """Mean and standard deviation over the finished child runs of `parent_run_id`, logged on the parent.

    For every name in `metric_names` it logs `<name>_mean` and `<name>_std` (population std, ddof=0,
    over the children's last logged values) and returns them. A metric no child logged is an error.
    """
    client = mlflow.MlflowClient()
    parent = client.get_run(parent_run_id)
    children = client.search_runs(
        [parent.info.experiment_id],
        filter_string=f"tags.`{PARENT_RUN_TAG}` = '{parent_run_id}' and attributes.status = 'FINISHED'",
    )
    summary: dict[str, float] = {}
    for name in metric_names:
        values = [child.data.metrics[name] for child in children if name in child.data.metrics]
        if not values:
            raise ValueError(
                f"no finished child run of {parent_run_id} logged metric {name!r} "
                f"({len(children)} finished children)"
            )
        summary[f"{name}_mean"] = float(np.mean(values))
        summary[f"{name}_std"] = float(np.std(values))
    for key, value in summary.items():
        client.log_metric(parent_run_id, key, value)
    return summary
