"""The benchmarks' reference YOLOv5s: like for like with ours when installed, a clear skip when not."""

from __future__ import annotations

import importlib.util
import sys

import pytest
import torch

from spacetrack.config import REPO_ROOT
from spacetrack.models.yolo import YOLOv5

sys.path.insert(0, str(REPO_ROOT / "benchmarks"))
import peer_yolov5  # noqa: E402

pytestmark = pytest.mark.usefixtures("one_torch_thread")


def test_a_missing_peer_is_left_out_with_the_way_to_install_it(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "yolov5" else real(name, *a)
    )
    model, why = peer_yolov5.reference_yolov5s(3)
    assert model is None
    assert "yolov5 package is not installed" in why and "make bench-peer-detector" in why and "7.0.14" in why


@pytest.mark.skipif(
    importlib.util.find_spec("yolov5") is None, reason="yolov5 not installed (make bench-peer-detector)"
)
def test_the_peer_decodes_the_same_boxes_as_our_predict():
    peer, what = peer_yolov5.reference_yolov5s(3)
    ours = YOLOv5(num_classes=3).eval()
    x = torch.rand(1, 3, 64, 96)
    with torch.inference_mode():
        theirs = peer(x)
        mine = ours.predict(x)
    theirs = theirs[0] if isinstance(theirs, (tuple, list)) else theirs
    assert theirs.shape == mine.shape == (1, 3 * (8 * 12 + 4 * 6 + 2 * 3), 8)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in peer.modules())  # fused, as timed
    assert (
        abs(sum(p.numel() for p in peer.parameters()) - sum(p.numel() for p in ours.parameters()))
        < 0.01 * 7e6
    )
    assert "random init" in what
