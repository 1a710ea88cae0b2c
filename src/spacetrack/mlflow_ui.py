"""Links into the MLflow UI that `make ui` serves, and the views that pin the columns that matter.

MLflow 3 opens an experiment on its GenAI pages; `#/experiments/<id>/runs?workflowType=machine_learning`
opens the runs table. The columns shown come from a view saved on the experiment: the UI's "Views -> Save
view" stores it in the experiment tag `mlflow.sharedViewState.<key>` (a JSON envelope: name, times and the
state, itself JSON: search filter, sort, columns, their order and widths) and opens it with
`&viewStateShareKey=<key>` on the runs route (the bare experiment route redirects and drops the key).
`save_view` writes such a tag, so a link opens a table that shows the swept values and the scores at once,
and the view is listed under "Views" by its name.

    python -m spacetrack.mlflow_ui      # (make ui does this first) pin each experiment's columns, print links
"""

from __future__ import annotations

import json
import os
import re
import time
from collections.abc import Sequence
from urllib.parse import quote

import mlflow
from mlflow.exceptions import MlflowException

from spacetrack.mlflow_log import DEFAULT_TRACKING_URI, tracking_uri

VIEW_TAG = "mlflow.sharedViewState."
DEFAULT_VIEW = "spacetrack"
DEFAULT_VIEW_NAME = "spacetrack: headline columns"
RUN_NAME_COLUMN = "attributes.`Run Name`"  # the runs table's pinned name column
NAME_WIDTH = (190, 460)  # the UI's width of that column, and the most we widen it to
CHAR_PX = 6.2  # about one character of the table's font, in pixels
DEFAULT_PORT = "5000"
# what `make ui` serves: the store the shell names (mlflow.set_tracking_uri overwrites the variable later)
SHELL_TRACKING_URI = os.environ.get("MLFLOW_TRACKING_URI")
# the scores a person looks for first, in this order; each experiment shows those its runs logged
HEADLINE_METRICS = (
    *("mota_best", "mota_mean", "mota_std", "mota", "idf1", "idsw", "fp", "fn", "fps"),
    *("best_map50_mean", "best_map50_std", "best_map50", "best_map50_95", "best_precision", "best_recall"),
    *("rank1_mean", "rank1_std", "rank1", "mAP_mean", "mAP", "pair_same_below_0.1"),
    *("overall.fusion.pixel_f1", "overall.fusion.blob_recall", "sequences", "frames", "boxes"),
)
HEADLINE_PARAMS = ("fold", "data.name", "tracker._target_", "model.gam_position")


def ui_base(uri: str | None = None) -> str:
    """The UI's address: the tracking server itself, or `make ui`'s http://127.0.0.1:$PORT (5000)."""
    uri = tracking_uri(uri)
    if uri.startswith(("http://", "https://")):
        return uri.rstrip("/")
    return f"http://127.0.0.1:{os.environ.get('PORT') or DEFAULT_PORT}"


def served_note(uri: str) -> str:
    """'' when `make ui` serves `uri` as it is; else how to make it serve it."""
    if uri.startswith(("http://", "https://")) or uri == tracking_uri(
        SHELL_TRACKING_URI or DEFAULT_TRACKING_URI
    ):
        return ""
    return f" (serve that store with: MLFLOW_TRACKING_URI={uri} make ui)"


def run_url(experiment_id: str, run_id: str, uri: str | None = None) -> str:
    return f"{ui_base(uri)}/#/experiments/{experiment_id}/runs/{run_id}"


def runs_view_url(experiment_id: str, view: str | None = None, uri: str | None = None) -> str:
    """The experiment's runs table, with the columns of saved view `view` when given."""
    query = "workflowType=machine_learning" + (f"&viewStateShareKey={quote(view)}" if view else "")
    return f"{ui_base(uri)}/#/experiments/{experiment_id}/runs?{query}"


def last_run_url() -> str | None:
    """URL of the run this process logged last (None when it logged none), with a note when the store is
    not the one `make ui` serves by default."""
    run = mlflow.last_active_run()
    if run is None:
        return None
    uri = mlflow.get_tracking_uri()
    return run_url(run.info.experiment_id, run.info.run_id, uri) + served_note(uri)


def column(kind: str, key: str) -> str:
    """A runs-table column id: kind is attributes, params, metrics or tags."""
    return f"{kind}.`{key}`"


def save_view(
    client: mlflow.MlflowClient,
    experiment_id: str,
    key: str,
    *,
    columns: Sequence[str],
    search_filter: str = "",
    order_by: str = "attributes.start_time",
    ascending: bool = False,
    name: str | None = None,
) -> None:
    """Store a runs-table view on the experiment under `key`, as the UI's "Save view" does: `columns` shown
    (metrics first, in the given order, then params, as the table groups them), the name column as wide as
    the longest name the filter shows. `name` (default: the sweep run `key` names, else `key`) is what the
    "Views" menu lists."""
    metrics = [c for c in columns if c.startswith("metrics.")]
    order = [RUN_NAME_COLUMN, *metrics, *[c for c in columns if c not in metrics]]
    widths = {RUN_NAME_COLUMN: _name_width(client, experiment_id, search_filter)}
    widths |= {c: _header_width(c) for c in columns if c.startswith("params.")}
    state = {
        "searchFilter": search_filter,
        "orderByKey": order_by,
        "orderByAsc": ascending,
        "startTime": "ALL",
        "lifecycleFilter": "Active",
        "modelVersionFilter": "All Runs",
        "datasetsFilter": [],
        "selectedColumns": list(columns),
        "columnOrder": order,
        "columnWidths": widths,
    }
    tag = VIEW_TAG + key
    now = int(time.time() * 1000)
    try:
        created = json.loads(client.get_experiment(experiment_id).tags[tag])["createdAt"]
    except (KeyError, TypeError, ValueError):
        created = now
    envelope = {
        "name": name or _run_view_name(client, key) or key,
        "createdAt": created,
        "updatedAt": now,
        "state": json.dumps(state),
        **state,  # and the bare state, the format before the envelope (the UI still reads it)
    }
    client.set_experiment_tag(experiment_id, tag, json.dumps(envelope))


def load_view(tags: dict[str, str], key: str) -> dict:
    """The state of view `key` among an experiment's tags (both the envelope and the bare state)."""
    value = json.loads(tags[VIEW_TAG + key])
    return json.loads(value["state"]) if isinstance(value.get("state"), str) else value


def _name_width(client: mlflow.MlflowClient, experiment_id: str, search_filter: str) -> int:
    runs = client.search_runs([experiment_id], search_filter, max_results=200)
    longest = max((len(r.info.run_name or "") for r in runs), default=0)
    return int(min(max(NAME_WIDTH[0], 60 + CHAR_PX * longest), NAME_WIDTH[1]))


def _header_width(column_id: str) -> int:
    return int(min(max(100, 30 + CHAR_PX * (len(column_id) - len("params.``"))), 240))


def _run_view_name(client: mlflow.MlflowClient, key: str) -> str | None:
    """'sweep 2026-12-01 20:33: max_cosine_distance x max_iou_distance' when `key` is a sweep's run id."""
    if not re.fullmatch(r"[0-9a-f]{32}", key):
        return None
    try:
        run = client.get_run(key)
    except MlflowException:
        return None
    started = time.strftime("%Y-%m-%d %H:%M", time.localtime(run.info.start_time / 1000))
    swept = [k.rsplit(".", 1)[-1] for k in run.data.tags.get("swept", "").split(",") if k]
    return f"{run.info.run_name} {started}" + (f": {' x '.join(swept)}" if swept else "")


def headline_columns(client: mlflow.MlflowClient, experiment_id: str, max_runs: int = 200) -> list[str]:
    """The headline params and metrics that the experiment's newest runs logged, plus swept params."""
    runs = client.search_runs([experiment_id], max_results=max_runs, order_by=["attributes.start_time DESC"])
    metrics = {k for r in runs for k in r.data.metrics}
    params = {k for r in runs for k in r.data.params}
    swept = {k for r in runs for k in r.data.tags.get("swept", "").split(",") if k}
    shown = [column("params", k) for k in HEADLINE_PARAMS if k in params and k not in swept]
    shown += [column("params", k) for k in sorted(swept) if k in params]
    return shown + [column("metrics", k) for k in HEADLINE_METRICS if k in metrics]


def pin_views(uri: str | None = None) -> list[tuple[str, str]]:
    """Save the headline view on every experiment of the store; (name, link) per experiment."""
    uri = tracking_uri(uri)
    client = mlflow.MlflowClient(tracking_uri=uri)
    links = []
    for experiment in client.search_experiments(order_by=["last_update_time DESC"]):
        if experiment.name == "Default" and not client.search_runs([experiment.experiment_id], max_results=1):
            continue
        save_view(
            client,
            experiment.experiment_id,
            DEFAULT_VIEW,
            columns=headline_columns(client, experiment.experiment_id),
            name=DEFAULT_VIEW_NAME,
        )
        links.append((experiment.name, runs_view_url(experiment.experiment_id, DEFAULT_VIEW, uri)))
    return links


def main() -> None:
    uri = tracking_uri(None)
    links = pin_views(uri)
    if not links:
        print(f"no experiments yet in {uri}; run an entry point first (make demo)")
    for name, link in links:
        print(f"  {name:<14} {link}")


if __name__ == "__main__":
    main()
