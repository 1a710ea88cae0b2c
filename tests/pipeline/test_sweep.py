"""The sweep report: which keys were swept, the MOTA heatmap and the table."""

from __future__ import annotations

import json

from spacetrack.pipeline.sweep import SweepCallback, plot_sweep, sweep_table, swept_keys


def _points():
    return [
        {"overrides": {"fold": "3", "tracker.max_cosine_distance": c, "tracker.max_iou_distance": i},
         "metrics": {"mota": float(c) + float(i), "idf1": 0.5, "idsw": 1, "fp": 2, "fn": 3}}
        for c in ("0.1", "0.2") for i in ("0.3", "0.5", "0.7")
    ]  # fmt: skip


def test_swept_keys_leave_out_fixed_ones():
    keys = swept_keys([p["overrides"] for p in _points()])
    assert keys == ["tracker.max_cosine_distance", "tracker.max_iou_distance"]


def test_heatmap_table_and_report(tmp_path):
    points = _points()
    keys = swept_keys([p["overrides"] for p in points])
    assert plot_sweep(points, keys, "mota", tmp_path / "h.png") and (tmp_path / "h.png").stat().st_size > 0
    assert not plot_sweep(points, [], "mota", tmp_path / "none.png")
    table = sweep_table(points, keys, ["mota"])
    assert table.splitlines()[2] == "| 0.1 | 0.3 | 0.4 |"
    callback = SweepCallback(metric="mota")
    callback.points = points
    callback._report(tmp_path / "sweep")
    record = json.loads((tmp_path / "sweep" / "sweep.json").read_text())
    assert record["best"]["overrides"]["tracker.max_iou_distance"] == "0.7"
    assert record["best"]["overrides"]["tracker.max_cosine_distance"] == "0.2"
    assert (tmp_path / "sweep" / "heatmap.png").is_file() and (tmp_path / "sweep" / "sweep.md").is_file()


def test_a_sweep_over_folds_gets_bars_with_the_mean(tmp_path):
    points = [
        {"overrides": {"fold": str(k), "video": "false"}, "metrics": {"mota": 0.1 * k, "idf1": 0.5}}
        for k in range(3)
    ]
    callback = SweepCallback(metric="mota")
    callback.points = points
    callback._report(tmp_path / "cv")
    record = json.loads((tmp_path / "cv" / "sweep.json").read_text())
    assert record["swept"] == ["fold"]
    assert abs(record["mota_mean"] - 0.1) < 1e-9 and abs(record["mota_std"] - 0.0816497) < 1e-6
    assert (tmp_path / "cv" / "bars.png").stat().st_size > 0
    assert not (tmp_path / "cv" / "heatmap.png").exists()
