"""The console of the entry points, run as a user runs them (a subprocess): one line and exit status 2 for
each kind of user error, the traceback for internal errors and with --verbose, and the summary line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from spacetrack import cli, track
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.data.layout import FORMAT_VERSION, load_manifest

STATIC_SEQ = "seq_005_static_distractors"
QUIET = ["logger=none", "progress=false"]


def run_entry(module: str, *args: str, env: dict | None = None) -> subprocess.CompletedProcess:
    environ = {k: v for k, v in os.environ.items() if k not in ("HYDRA_FULL_ERROR", "MLFLOW_TRACKING_URI")}
    environ |= {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", **(env or {})}
    return subprocess.run(
        [sys.executable, "-m", f"spacetrack.{module}", *args],
        capture_output=True,
        text=True,
        cwd=REPO_ROOT,
        env=environ,
        timeout=900,  # seconds; a few normally, but the tests share the machine
    )


def assert_user_error(result: subprocess.CompletedProcess, *expected: str) -> str:
    """Exit status 2, no traceback, and exactly one stderr line `spacetrack: error: ...` naming `expected`."""
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr + result.stdout
    assert "Error executing job" not in result.stderr  # Hydra's own line about the failed job
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    errors = [line for line in lines if line.startswith("spacetrack: error: ")]
    assert len(errors) == 1 and errors == lines[-1:], result.stderr
    for text in expected:
        assert text in errors[0], errors[0]
    return errors[0]


def test_unknown_config_key_is_one_line_and_verbose_shows_the_traceback():
    assert_user_error(run_entry("track_detections", "tracker.no_such_key=1"), "tracker.no_such_key", "+")
    assert_user_error(run_entry("track_detections", "tracker=no_such_tracker"), "tracker/no_such_tracker")
    for verbose in (["--verbose"], []):
        env = {} if verbose else {"HYDRA_FULL_ERROR": "1"}
        result = run_entry("track_detections", "tracker.no_such_key=1", *verbose, env=env)
        assert result.returncode == 1 and "Traceback" in result.stderr
        assert "spacetrack: error:" not in result.stderr


def test_malformed_detection_file(tmp_path):
    dets = np.zeros((3, 10))
    dets[:, 0] = [1, 2, 3]
    dets[:, 4:7] = [10, 10, 0.9]
    dets[1, 3] = np.nan
    np.save(tmp_path / "dets.npy", dets)
    result = run_entry(
        "track_detections", f"detections={tmp_path / 'dets.npy'}", f"output_file={tmp_path / 'out.txt'}",
        "tracker=sort", "logger=none",
    )  # fmt: skip
    assert_user_error(result, "dets.npy", "row 1")
    assert not (tmp_path / "out.txt").exists()


def test_bad_fold(tmp_path):
    dataset = tmp_path / "space_smoke"
    dataset.mkdir()
    manifest = {"name": "space_smoke", "format_version": FORMAT_VERSION, "num_folds": 9, "sequences": []}
    (dataset / "manifest.json").write_text(json.dumps(manifest))
    result = run_entry("track", "data=smoke", f"data_root={tmp_path}", "fold=12", *QUIET)
    assert_user_error(result, "fold 12 is outside 0..8")


@pytest.mark.parametrize("kind", ["missing", "truncated"])
def test_missing_or_truncated_video(tmp_path, kind):
    video = tmp_path / "clip.mp4"
    if kind == "truncated":
        video.write_bytes(b"\x00\x00\x00\x18ftypmp42" + bytes(200))
    result = run_entry("track", f"source={video}", *QUIET)
    assert_user_error(result, str(video), "does not exist" if kind == "missing" else "cannot open")


def test_missing_weights(tmp_path):
    frames = tmp_path / "frames"
    frames.mkdir()
    for k in (1, 2):
        cv2.imwrite(str(frames / f"{k:06d}.png"), np.zeros((48, 64, 3), np.uint8))
    missing = tmp_path / "best.pt"
    result = run_entry(
        "track", f"source={frames}", f"detector.weights={missing}", "reid.weights=none", "tracker=sort",
        *QUIET,
    )  # fmt: skip
    assert_user_error(result, str(missing), "not found")


@pytest.mark.slow
def test_stale_cache_without_rebuild(smoke_dataset, tmp_path):
    common = [
        "data=smoke", f"data_root={smoke_dataset.parent}", f"cache.dir={tmp_path / 'cache'}",
        f"output_dir={tmp_path / 'out'}", "detector=ground_truth", "reid.weights=none", "tracker=sort",
        f"sequence={STATIC_SEQ}", "video=false", "max_frames=8", *QUIET,
    ]  # fmt: skip
    track.run(compose_config("track", common))  # fills the cache
    result = run_entry("track", *common, "detector.score=0.9", "cache.rebuild=false")
    assert_user_error(result, STATIC_SEQ, "cache.rebuild=true")


def test_internal_errors_keep_their_traceback():
    code = "from spacetrack import cli; import numpy as np; cli.report_errors(lambda: np.zeros(2).reshape(3))"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 1 and "Traceback" in result.stderr and "reshape" in result.stderr
    assert "spacetrack: error:" not in result.stderr


def _raised(call) -> BaseException:
    try:
        call()
    except Exception as caught:
        return caught
    raise AssertionError(f"{call} raised nothing")


def _fail(exc: BaseException):
    raise exc


def test_which_errors_are_the_users(tmp_path):
    assert cli.user_error_message(_raised(lambda: _fail(cli.UserError("bad\n value")))) == "bad value"
    # a check of spacetrack's: the user's; the same class raised elsewhere (here, numpy): a bug
    message = cli.user_error_message(_raised(lambda: load_manifest(tmp_path)))
    assert message is not None and str(tmp_path) in message
    assert cli.user_error_message(_raised(lambda: _fail(FileNotFoundError("x")))) is None
    assert cli.user_error_message(_raised(lambda: np.zeros(2).reshape(3))) is None
    assert cli.user_error_message(_raised(lambda: _fail(RuntimeError("a bug")))) is None


def test_summary_line_names_metric_files_and_run_url(tmp_path):
    dets = np.zeros((3, 10))
    dets[:, 0] = [1, 2, 3]
    dets[:, 2:7] = [5, 5, 10, 10, 0.9]
    np.save(tmp_path / "dets.npy", dets)
    store = f"sqlite:///{tmp_path / 'mlflow.db'}"
    result = run_entry(
        "track_detections", f"detections={tmp_path / 'dets.npy'}", f"output_file={tmp_path / 'out.txt'}",
        "tracker=sort", f"logger.tracking_uri={store}", env={"PORT": "5123"},
    )  # fmt: skip
    assert result.returncode == 0, result.stderr
    line = result.stdout.strip().splitlines()[-1]
    assert line.startswith("spacetrack track_detections: num_tracks 1, ms_per_frame ")
    assert f"| files: {tmp_path / 'out.txt'} |" in line  # outside the working directory: absolute
    url = line.split("| MLflow: ")[1]
    assert url.startswith("http://127.0.0.1:5123/#/experiments/") and f"MLFLOW_TRACKING_URI={store}" in url
    run_id = url.split("/runs/")[1].split()[0]
    import mlflow

    assert mlflow.MlflowClient(tracking_uri=store).get_run(run_id).info.status == "FINISHED"
    assert Path(tmp_path / "out.txt").stat().st_size > 0
