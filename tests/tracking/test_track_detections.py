import subprocess
import sys

import numpy as np
import pytest
from hydra.errors import MissingConfigException

from spacetrack.config import compose_config
from spacetrack.track_detections import run

TABLE_2 = {  # max_cosine_distance, min_confidence, nms_max_overlap, max_iou_distance, n_init, nn_budget, max_age
    "deepsort_original": (0.2, 0.3, 0.5, 0.7, 3, 100, 70),
    "deepsort_paper": (0.1, 0.5, 1.0, 0.5, 6, 100, 70),
}
KEYS = ("max_cosine_distance", "min_confidence", "nms_max_overlap", "max_iou_distance", "n_init", "nn_budget")


def _compose(*overrides):
    return compose_config("track_detections", ["logger=none", *overrides])


def _write_sequence(tmp_path, num_frames=30):
    """Two targets moving right with distinct features; returns (detections path, gt path)."""
    rng = np.random.default_rng(0)
    rows, gt = [], []
    for f in range(1, num_frames + 1):
        for k, (y, feature) in enumerate([(100.0, [1, 0, 0]), (300.0, [0, 1, 0])], start=1):
            x = 50 + 4 * f
            gt.append(f"{f},{k},{x},{y},30,40,1,0,1")
            noise = rng.normal(0, 0.5, 2)
            rows.append([f, -1, x + noise[0], y + noise[1], 30, 40, 0.9, -1, -1, -1, *feature])
    dets, truth = tmp_path / "dets.npy", tmp_path / "gt.txt"
    np.save(dets, np.array(rows))
    truth.write_text("\n".join(gt) + "\n")
    return dets, truth


@pytest.mark.parametrize("preset", sorted(TABLE_2))
def test_presets_hold_table_2_exactly(preset):
    cfg = _compose(f"tracker={preset}")
    assert tuple(cfg.tracker[k] for k in KEYS) + (cfg.tracker.max_age,) == TABLE_2[preset]
    assert cfg.tracker.lambda_ == 0.0 and cfg.tracker.gating_threshold == 9.4877


def test_sort_preset_has_no_appearance_and_keys_are_overridable():
    cfg = _compose("tracker=sort", "tracker.n_init=2")
    assert cfg.tracker.max_cosine_distance is None and cfg.tracker.n_init == 2


def test_unknown_preset_is_a_clear_error():
    with pytest.raises(MissingConfigException, match="tracker/deepsort_fancy"):
        _compose("tracker=deepsort_fancy")


@pytest.mark.parametrize("preset", ["deepsort_original", "deepsort_paper", "sort"])
def test_run_writes_mot_results_and_scores_them(tmp_path, preset):
    dets, truth = _write_sequence(tmp_path)
    out = tmp_path / "out.txt"
    metrics = run(_compose(f"detections={dets}", f"output_file={out}", f"gt={truth}", f"tracker={preset}"))
    rows = np.loadtxt(out, delimiter=",")
    assert rows.shape[1] == 10 and set(rows[:, 1]) == {1, 2}
    assert (rows[:, 6:] == [1, -1, -1, -1]).all()
    n_init = _compose(f"tracker={preset}").tracker.n_init
    assert rows[:, 0].min() == n_init  # written from the hit that confirms the track
    assert metrics["idsw"] == 0 and metrics["fp"] == 0
    assert metrics["fn"] == 2 * (n_init - 1)  # only the frames before confirmation are missed
    assert metrics["num_frames"] == 30 and metrics["num_tracks"] == 2


def test_bad_input_writes_nothing(tmp_path):
    dets, _ = _write_sequence(tmp_path)
    bad = np.load(dets)
    bad[7, 5] = 0.0
    np.save(dets, bad)
    out = tmp_path / "out.txt"
    with pytest.raises(ValueError, match=r"dets.npy: row 7, h = 0.0 is not positive"):
        run(_compose(f"detections={dets}", f"output_file={out}"))
    assert sorted(p.name for p in tmp_path.iterdir()) == ["dets.npy", "gt.txt"]  # no output, no temp file


def test_boxes_without_features_need_the_sort_preset(tmp_path):
    dets, truth = _write_sequence(tmp_path)
    np.save(dets, np.load(dets)[:, :10])
    out = tmp_path / "out.txt"
    with pytest.raises(ValueError, match="dets.npy: no appearance features"):
        run(_compose(f"detections={dets}", f"output_file={out}"))
    metrics = run(_compose(f"detections={dets}", f"output_file={out}", f"gt={truth}", "tracker=sort"))
    assert metrics["idsw"] == 0 and metrics["num_tracks"] == 2


def test_run_logs_to_mlflow(tmp_path):
    mlflow = pytest.importorskip("mlflow")
    dets, truth = _write_sequence(tmp_path, num_frames=10)
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    cfg = _compose(f"detections={dets}", f"output_file={tmp_path / 'out.txt'}", f"gt={truth}")
    cfg.logger.enabled, cfg.logger.tracking_uri = True, uri
    run(cfg)
    client = mlflow.MlflowClient(uri)
    (run_info,) = client.search_runs([client.get_experiment_by_name("track_detections").experiment_id])
    assert run_info.data.params["tracker.n_init"] == "6"
    assert {"mota", "idf1", "ms_per_frame"} <= run_info.data.metrics.keys()


def test_command_line(tmp_path):
    dets, _ = _write_sequence(tmp_path, num_frames=8)
    out = tmp_path / "out.txt"
    cmd = [sys.executable, "-m", "spacetrack.track_detections", f"detections={dets}", f"output_file={out}"]
    done = subprocess.run(
        [*cmd, "logger=none", "tracker=deepsort_original"], capture_output=True, text=True, cwd=tmp_path
    )
    assert done.returncode == 0, done.stderr
    assert out.read_text().startswith("3,")
