"""The second-stage naming study: each object's class from the ground truth, each detection named from
its own crop."""

from __future__ import annotations

import importlib.util
import json

import numpy as np
import pytest
import torch

from spacetrack.config import REPO_ROOT
from spacetrack.reid.crops import Cropper

spec = importlib.util.spec_from_file_location(
    "second_stage", REPO_ROOT / "experiments/naming/second_stage.py"
)
study = importlib.util.module_from_spec(spec)
spec.loader.exec_module(study)


class Brightness(torch.nn.Module):
    """Feature: each crop's mean; head: class 1 for a crop brighter than 0.3, else class 0."""

    def forward(self, crops):
        return crops.mean(dim=(1, 2, 3))[:, None]


def test_each_detection_is_named_from_its_own_crop():
    image = torch.zeros(3, 64, 96)
    image[:, 10:20, 60:80] = 1.0  # one lit object; the rest is sky
    detections = np.array([[60, 10, 80, 20, 0.9, 0.0], [5, 40, 15, 50, 0.8, 1.0]], dtype=np.float32)
    head = lambda f: torch.cat([0.3 - f, f - 0.3], dim=1)  # noqa: E731
    cropper = Cropper(height=16, width=16, margin=0.0, min_size=1.0)
    classes = study.renamer(Brightness(), head, cropper)(image, detections)
    assert classes.tolist() == [1.0, 0.0] and classes.dtype == detections.dtype


def test_predict_batches_and_empty():
    net, head = Brightness(), lambda f: torch.cat([0.3 - f, f - 0.3], dim=1)
    crops = torch.cat([torch.ones(3, 3, 4, 4), torch.zeros(2, 3, 4, 4)])
    assert study.predict(net, head, crops, batch=2).tolist() == [1, 1, 1, 0, 0]
    assert len(study.predict(net, head, crops[:0])) == 0


def test_a_detector_on_enhanced_frames_is_refused(monkeypatch):
    monkeypatch.setattr("sys.argv", ["second_stage.py", "--fold", "0", "--", "enhance=dwt_hsv"])
    with pytest.raises(SystemExit, match="frames as rendered"):
        study.main()


faint_views_spec = importlib.util.spec_from_file_location(
    "faint_views", REPO_ROOT / "experiments/naming/faint_views.py"
)
faint_views = importlib.util.module_from_spec(faint_views_spec)
faint_views_spec.loader.exec_module(faint_views)


def test_faint_objects_count_labelled_frames_seen_in_small_part(tmp_path):
    manifest = {"format_version": 1, "class_names": ["satellite", "rocket_body", "debris"],
                "sequences": [{"name": "seq_a", "fold": 3}]}  # fmt: skip
    (tmp_path / "manifest.json").write_text(json.dumps(manifest))
    gt = tmp_path / "seq_a" / "gt"
    gt.mkdir(parents=True)
    # rocket body 1: three labelled frames at 0.1 seen, one unlabelled (conf 0); satellite 2: one at 0.1
    (gt / "gt.txt").write_text(
        "1,1,0,0,5,5,1,1,0.1\n2,1,0,0,5,5,1,1,0.1\n3,1,0,0,5,5,1,1,0.15\n4,1,0,0,5,5,0,1,0.1\n"
        "1,2,9,9,5,5,1,0,0.1\n2,2,9,9,5,5,1,0,0.9\n"
    )
    (gt / "static.txt").write_text("")
    totals, faint = faint_views.faint_objects(tmp_path, max_visibility=0.2, min_frames=3)
    assert totals == {"satellite": 1, "rocket_body": 1, "debris": 0}
    assert faint == [{"sequence": "seq_a", "fold": 3, "id": 1, "class": "rocket_body", "labelled_frames": 3,
                      "faint_frames": 3, "median_visibility": 0.1}]  # fmt: skip
