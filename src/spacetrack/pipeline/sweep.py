"""A Hydra callback that makes a multirun of `spacetrack.track` one MLflow sweep with a MOTA heatmap.

On multirun start it opens a parent run and exports its id as `SPACETRACK_SWEEP_PARENT_RUN_ID` (the track
config reads it into `sweep_parent_run_id`, so each point's run becomes a child, named after its swept
values). After each job it records the point's overrides and `metrics.json`; at the end it writes
`sweep.json`, `sweep.md` and `heatmap.png` when two keys were swept (the metric over the grid) or
`bars.png` when one was (the metric per value with the mean: over folds, `make track-cv`'s chart) into
the sweep folder, and logs them on the parent with the best point (`<metric>_best`, `best.<key>` params,
tag `best`) or, over folds alone, the metric's mean and std. The parent's description says what was swept
and links a view of the points' table (swept values and scores as columns, best first), the link the
summary line prints.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import mlflow
import numpy as np
from hydra.core.utils import JobReturn, JobStatus
from matplotlib.figure import Figure
from omegaconf import DictConfig

from spacetrack import mlflow_ui
from spacetrack.io import atomic_write_text
from spacetrack.mlflow_log import NOTE_TAG, PARENT_RUN_TAG, point_name
from spacetrack.multirun import MultirunParent

PARENT_ENV = "SPACETRACK_SWEEP_PARENT_RUN_ID"
SHOWN = ("mota", "idf1", "idsw", "fp", "fn")  # the scores of sweep.md and of the points' table


def swept_keys(points: list[dict[str, str]]) -> list[str]:
    """Override keys whose value differs between points, in the order the first point gives them."""
    return [k for k in points[0] if len({p.get(k) for p in points}) > 1] if points else []


def _number(text: str) -> float | str:
    try:
        return float(text)
    except ValueError:
        return text


def _label(value: float | str) -> str:
    return str(int(value)) if isinstance(value, float) and value.is_integer() else str(value)


def _sorted(values: set) -> list:
    try:
        return sorted(values)
    except TypeError:  # numbers mixed with words
        return sorted(values, key=str)


def plot_sweep(points: list[dict], keys: list[str], metric: str, path: Path) -> bool:
    """Heatmap of `metric` over two swept keys, or bars over one; False (nothing drawn) otherwise."""
    if len(keys) not in (1, 2):
        return False
    fig = Figure(figsize=(5.5, 4.2))
    ax = fig.subplots()
    if len(keys) == 1:
        labels = [str(p["overrides"][keys[0]]) for p in points]
        values = [p["metrics"].get(metric, np.nan) for p in points]
        ax.bar(range(len(labels)), values, color="tab:blue")  # positions: labels like "3" stay labels
        ax.set_xticks(range(len(labels)), labels)
        mean = float(np.nanmean(values))
        ax.axhline(mean, color="k", ls="--", label=f"mean {mean:.3f} ± {float(np.nanstd(values)):.3f}")
        ax.set_xlabel(keys[0])
        ax.set_ylabel(metric)
        ax.legend()
    else:
        xs = _sorted({_number(p["overrides"][keys[0]]) for p in points})
        ys = _sorted({_number(p["overrides"][keys[1]]) for p in points})
        grid = np.full((len(ys), len(xs)), np.nan)
        for p in points:
            i = ys.index(_number(p["overrides"][keys[1]]))
            j = xs.index(_number(p["overrides"][keys[0]]))
            grid[i, j] = p["metrics"].get(metric, np.nan)
        image = ax.imshow(grid, origin="lower", cmap="viridis", aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, f"{v:.3f}", ha="center", va="center", color="w", fontsize=9)
        ax.set_xticks(range(len(xs)), [_label(x) for x in xs])
        ax.set_yticks(range(len(ys)), [_label(y) for y in ys])
        ax.set_xlabel(keys[0])
        ax.set_ylabel(keys[1])
        fig.colorbar(image, ax=ax, label=metric)
    ax.set_title(f"{metric} per {keys[0]}" if len(keys) == 1 else f"{metric} per sweep point")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    return True


def sweep_table(points: list[dict], keys: list[str], metrics: list[str]) -> str:
    head = "| " + " | ".join(keys + metrics) + " |\n|" + "---|" * (len(keys) + len(metrics)) + "\n"
    body = "".join(
        "| "
        + " | ".join(
            [str(p["overrides"][k]) for k in keys]
            + [f"{p['metrics'].get(m, float('nan')):.4g}" for m in metrics]
        )
        + " |\n"
        for p in points
    )
    return head + body


class SweepCallback(MultirunParent):
    """metric: the score the heatmap shows and the best point maximises (a key of metrics.json)."""

    env_var = PARENT_ENV
    run_name = "sweep"
    tags = {"sweep": "parent"}

    def __init__(self, *, metric: str = "mota") -> None:
        super().__init__()
        self.metric = metric
        self.points: list[dict[str, Any]] = []
        self.record: dict[str, Any] = {}

    def start(self, config: DictConfig) -> None:
        self.points = []

    def on_job_end(self, config: DictConfig, job_return: JobReturn, **kwargs: Any) -> None:
        super().on_job_end(config, job_return, **kwargs)
        if job_return.status != JobStatus.COMPLETED:
            return
        out_dir = Path(job_return.hydra_cfg.hydra.runtime.output_dir)
        metrics_path = out_dir / "metrics.json"
        metrics = json.loads(metrics_path.read_text()) if metrics_path.is_file() else {}
        overrides = dict(
            o.split("=", 1) for o in job_return.overrides if "=" in o and not o.startswith("+sweep")
        )
        # relative to the working directory, so a committed sweep.json names no path of this machine
        self.points.append(
            {"overrides": overrides, "metrics": metrics, "output_dir": os.path.relpath(out_dir)}
        )

    def finish(self, *, failed: bool) -> None:
        # the points that finished are reported even when another point failed
        if self.points:
            self._report(Path(self._folder))

    def headline(self) -> str:
        best, m = self.record.get("best"), self.metric
        if f"{m}_mean" in self.record:
            return f"{m}_mean {self.record[f'{m}_mean']:.4g} ± {self.record[f'{m}_std']:.4g}"
        if best is None:
            return f"no point gave {m}" if self.points else "no point finished"
        return f"{m}_best {best['metrics'][m]:.4g} at {point_name(_swept_values(best, self.record['swept']))}"

    def parent_url(self) -> str | None:
        """The runs table of this sweep's points (swept values and scores as columns), when logged."""
        if self.parent_id is None:
            return None
        experiment = mlflow.MlflowClient().get_run(self.parent_id).info.experiment_id
        uri = mlflow.get_tracking_uri()
        return mlflow_ui.runs_view_url(experiment, self.parent_id, uri) + mlflow_ui.served_note(uri)

    def _report(self, folder: Path) -> None:
        folder.mkdir(parents=True, exist_ok=True)
        keys = swept_keys([p["overrides"] for p in self.points])
        values = [p["metrics"].get(self.metric, np.nan) for p in self.points]
        best = self.points[int(np.nanargmax(values))] if not np.all(np.isnan(values)) else None
        record: dict[str, Any] = {"metric": self.metric, "swept": keys, "best": best, "points": self.points}
        if keys == ["fold"]:  # a cross-validation: the spread over folds is the result, not the best fold
            record |= {
                f"{self.metric}_mean": float(np.nanmean(values)),
                f"{self.metric}_std": float(np.nanstd(values)),
            }
        elif best is not None:
            record[f"{self.metric}_best"] = float(best["metrics"][self.metric])
        self.record = record
        atomic_write_text(folder / "sweep.json", json.dumps(record, indent=2) + "\n")
        shown = [self.metric] + [m for m in SHOWN if m != self.metric]
        atomic_write_text(folder / "sweep.md", sweep_table(self.points, keys, shown))
        artifacts = [folder / "sweep.json", folder / "sweep.md"]
        chart = folder / ("heatmap.png" if len(keys) == 2 else "bars.png")
        if plot_sweep(self.points, keys, self.metric, chart):
            artifacts.append(chart)
        if self.parent_id is not None:
            self._log_parent(record, keys, shown, artifacts)

    def _log_parent(self, record: dict, keys: list[str], shown: list[str], artifacts: list[Path]) -> None:
        """Metrics, the best point and its description on the parent; a view of the points' table."""
        client = mlflow.MlflowClient()
        for key in (f"{self.metric}_mean", f"{self.metric}_std", f"{self.metric}_best"):
            if key in record and np.isfinite(record[key]):
                client.log_metric(self.parent_id, key, record[key])
        experiment = client.get_run(self.parent_id).info.experiment_id
        mlflow_ui.save_view(
            client,
            experiment,
            self.parent_id,
            columns=[mlflow_ui.column("params", k) for k in keys]
            + [mlflow_ui.column("metrics", m) for m in shown],
            search_filter=f"tags.`{PARENT_RUN_TAG}` = '{self.parent_id}'",
            order_by=mlflow_ui.column("metrics", self.metric),
        )
        note = self.description + f" Results in `{os.path.relpath(self._folder)}`."
        if record["best"] is not None:
            values = _swept_values(record["best"], keys)
            for k, v in record["best"]["overrides"].items():
                client.log_param(self.parent_id, f"best.{k}", v)
            client.set_tag(self.parent_id, "best", point_name(values))
            note += f" Best: {self.headline()}."
        link = mlflow_ui.runs_view_url(experiment, self.parent_id, mlflow.get_tracking_uri())
        client.set_tag(
            self.parent_id, NOTE_TAG, note + f" [The {len(self.points)} points side by side]({link})"
        )
        for path in artifacts:
            client.log_artifact(self.parent_id, str(path), "sweep")


def _swept_values(point: dict, keys: list[str]) -> dict[str, str]:
    return {k: point["overrides"][k] for k in keys}
