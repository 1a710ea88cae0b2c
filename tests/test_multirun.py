"""Multirun parent runs close whether the multirun ends normally or a job fails."""

from __future__ import annotations

import os

import mlflow
import pytest
from omegaconf import OmegaConf

from spacetrack.multirun import MultirunParent


class Recording(MultirunParent):
    env_var = "SPACETRACK_TEST_PARENT_RUN_ID"
    run_name = "test-parent"

    def __init__(self) -> None:
        super().__init__()
        self.finished: list[bool] = []

    def finish(self, *, failed: bool) -> None:
        self.finished.append(failed)


def _config(tmp_path):
    return OmegaConf.create(
        {
            "task_name": "t",
            "logger": {"enabled": True, "tracking_uri": f"sqlite:///{tmp_path}/m.db", "experiment": "t"},
            "hydra": {"overrides": {"task": ["fold=0,1"]}},
        }
    )


@pytest.mark.parametrize("failed,status", [(False, "FINISHED"), (True, "FAILED")])
def test_parent_run_is_closed_and_the_variable_cleared(tmp_path, monkeypatch, failed, status):
    monkeypatch.delenv("MLFLOW_TRACKING_URI", raising=False)
    callback = Recording()
    callback.on_multirun_start(_config(tmp_path))
    parent = os.environ[callback.env_var]
    if failed:
        callback._end(failed=True)  # what the exit hook does when Hydra skips on_multirun_end
    else:
        callback.on_multirun_end(_config(tmp_path))
    assert callback.finished == [failed]
    assert callback.env_var not in os.environ
    assert mlflow.active_run() is None
    assert mlflow.MlflowClient().get_run(parent).info.status == status
