"""Finding a fold's trained detector and re-ID weights through MLflow (experiments `detector` and `reid`).

The training entry points log one run per fold (tag `fold`, parameter `data.name`) with the weights as
an artifact; the newest finished run that matches wins. A fold with no such run is an error naming the
command that makes one.
"""

from __future__ import annotations

from pathlib import Path

import mlflow

from spacetrack.mlflow_log import artifact_file, finished_runs
from spacetrack.mlflow_log import tracking_uri as resolve_uri


class MissingWeightsError(FileNotFoundError):
    """No trained weights for what was asked; the message names the command that trains them.

    `train` is that command as (module, overrides): `python -m <module> <overrides...>` trains them.
    """

    def __init__(self, message: str, train: tuple[str, list[str]] | None = None) -> None:
        super().__init__(message)
        self.train = train


def train_command(module: str, overrides: list[str]) -> str:
    """The make target that runs `python -m module overrides` (fold=K becomes FOLD=K)."""
    target = {"spacetrack.train": "train", "spacetrack.train_reid": "train-reid"}[module]
    fold = [o.split("=", 1)[1] for o in overrides if o.startswith("fold=")]
    rest = [o for o in overrides if not o.startswith("fold=")]
    return (
        f"make {target}"
        + (f" FOLD={fold[0]}" if fold else "")
        + (f' ARGS="{" ".join(rest)}"' if rest else "")
    )


def fold_artifact(
    *,
    experiment: str,
    fold: int,
    dataset: str,
    artifact: str,
    train: tuple[str, list[str]],
    tags: dict[str, str] | None = None,
    tag_defaults: dict[str, str] | None = None,
    tracking_uri: str | None = None,
) -> Path:
    """Local path of `artifact` of the newest FINISHED run of `experiment` for `fold` on `dataset`.

    tags: further tags the run must carry (e.g. {"gam_position": "after_sppf", "enhance": "dwt_hsv"}).
    train: (module, overrides) of the command that makes such a run, named in the error when none is found.
    tag_defaults: the value a tag of `tags` has on runs that lack it (runs made before it was added).
    """
    uri = resolve_uri(tracking_uri)
    client = mlflow.MlflowClient(tracking_uri=uri)
    wanted = {"fold": str(fold), **(tags or {})}
    defaults = tag_defaults or {}
    searched = {k: v for k, v in wanted.items() if k not in defaults}
    runs = finished_runs(
        experiment, tags=searched, params={"data.name": dataset}, tracking_uri=uri, max_results=20
    )
    for run in runs:
        if any(run.data.tags.get(k, d) != wanted[k] for k, d in defaults.items() if k in wanted):
            continue
        names = {a.path for a in client.list_artifacts(run.info.run_id, str(Path(artifact).parent))}
        if artifact in names:
            return artifact_file(run.info.run_id, artifact, tracking_uri=uri)
    described = ", ".join(f"{k}={v}" for k, v in wanted.items())
    raise MissingWeightsError(
        f"no trained weights for fold {fold} of {dataset} ({described}) in MLflow experiment "
        f"{experiment!r} on {uri}: make them with `{train_command(*train)}`, or give the path in the config",
        train=train,
    )
