"""The launcher presets: local_parallel runs a multirun's jobs in parallel processes; slurm builds
the submitit launcher from settings its plugin accepts (a key outside its schema fails to compose)."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from hydra.errors import ConfigCompositionException
from hydra.utils import instantiate

from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.evaluation import OVERALL


def test_local_parallel_runs_each_job_of_a_multirun(tmp_path):
    gt, results = tmp_path / "gt.txt", tmp_path / "results.txt"
    gt.write_text("1,1,0,0,20,20,1,0,1\n2,1,0,0,20,20,1,0,1\n")
    results.write_text("1,5,0,0,20,20,1,-1,-1,-1\n2,5,6,0,20,20,1,-1,-1,-1\n")  # frame 2 at IoU 0.54
    sweep = tmp_path / "multi"
    cmd = [sys.executable, "-m", "spacetrack.evaluate", "-m", "hydra/launcher=local_parallel",
           f"results={results}", f"gt={gt}", "iou_threshold=0.5,0.9", "logger=none",
           f"hydra.sweep.dir={sweep}", "output_file=${hydra:runtime.output_dir}/metrics.json"]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO_ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    assert "Joblib.Parallel(n_jobs=2" in done.stdout + done.stderr  # the preset, not the basic launcher
    mota = [json.loads((sweep / str(k) / "metrics.json").read_text())[OVERALL]["mota"] for k in (0, 1)]
    assert mota == [1.0, 0.0]  # both matched at IoU 0.5; at 0.9 frame 2 is a miss and a false positive


def test_slurm_preset_builds_the_submitit_launcher_with_its_settings():
    overrides = ["hydra/launcher=slurm", "hydra.launcher.partition=gpu", "hydra.launcher.gpus_per_node=2"]
    launcher = instantiate(compose_config("train", overrides, return_hydra_config=True).hydra.launcher)
    assert type(launcher).__name__ == "SlurmLauncher"
    assert (launcher.params["partition"], launcher.params["tasks_per_node"]) == ("gpu", 2)
    with pytest.raises(ConfigCompositionException, match="gpus_per_nod"):  # not in the plugin's schema
        compose_config(
            "train", ["hydra/launcher=slurm", "hydra.launcher.gpus_per_nod=2"], return_hydra_config=True
        )
