"""`make demo` end to end on the smoke data: ground-truth clip, then the pipeline with the shipped weights."""

from __future__ import annotations

import json

import cv2
import pytest

from spacetrack import demo
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.data.layout import read_mot
from spacetrack.evaluation import evaluate


def test_demo_writes_clip_and_tracks_with_the_shipped_weights(tmp_path, smoke_dataset):
    weights = REPO_ROOT / "weights"
    cfg = compose_config(
        "demo",
        [
            "data=smoke",
            f"data_root={smoke_dataset.parent}",
            f"output_dir={tmp_path / 'demo'}",
            "logger=none",
            "progress=false",
            f"track.detector_weights={weights / 'detector_yolov5s_fold3.pt'}",
            f"track.reid_weights={weights / 'reid_fold3.pt'}",
        ],
    )
    result = demo.run(cfg)
    out = tmp_path / "demo"
    clip = out / "seq_003_occlusion_ground_truth.mp4"
    capture = cv2.VideoCapture(str(clip))
    assert int(capture.get(cv2.CAP_PROP_FRAME_COUNT)) == 48
    tracked = out / "track"
    rows = (tracked / "seq_003_occlusion.txt").read_text().splitlines()
    assert rows and all(len(r.split(",")) == 10 for r in rows)
    assert (tracked / "seq_003_occlusion.mp4").stat().st_size > 0
    metrics = json.loads((tracked / "metrics.json").read_text())
    assert {k: metrics[k] for k in ("mota", "idf1", "idsw")} == {
        k: result[k] for k in ("mota", "idf1", "idsw")
    }
    # the reported scores are those of the written tracks against the clip's ground truth
    gt = read_mot(smoke_dataset / "seq_003_occlusion" / "gt" / "gt.txt")
    rescored = evaluate({"clip": (gt, read_mot(tracked / "seq_003_occlusion.txt"))})["clip"]
    assert rescored["mota"] == pytest.approx(result["mota"], abs=0.01)
    assert 0.0 < result["mota"] <= 1.0
