"""The reference YOLOv5s: the registry's `yolov5` package (the packaged ultralytics v7.0 code) as a peer.

It is an optional extra (`pip install -e .[bench]`, or `make bench-peer-detector`); the benchmarks skip
it with the reason when it is missing. The network is built from the package's own `yolov5s.yaml`
(random init, nothing downloaded), Conv+BN fused and in eval mode, as its `detect.py` runs it; its
forward in eval mode decodes the boxes, as our `predict` does.
"""

from __future__ import annotations

import importlib.util
import logging
import sys
import types
from pathlib import Path

import torch

PACKAGE = "yolov5==7.0.14"
INSTALL = f"run `make bench-peer-detector`: pip install --no-deps {PACKAGE} and what its model code imports"


def _pkg_resources_shim() -> None:
    """yolov5 7.0.14 imports `pkg_resources` for `parse_version` only; setuptools 81 and later no longer
    ship it, so when it is missing a module with that one function stands in."""
    if importlib.util.find_spec("pkg_resources") is None and "pkg_resources" not in sys.modules:
        from packaging.version import parse

        shim = types.ModuleType("pkg_resources")
        shim.parse_version = parse
        sys.modules["pkg_resources"] = shim


def reference_yolov5s(num_classes: int) -> tuple[torch.nn.Module | None, str]:
    """(the peer network, fused and in eval mode, or None; what it is, or why it is missing)."""
    if importlib.util.find_spec("yolov5") is None:
        return None, f"the reference YOLOv5s is left out: the yolov5 package is not installed ({INSTALL})"
    import cv2

    cv_threads = cv2.getNumThreads()  # the package sets OpenCV to one thread on import; ours keep theirs
    torch_threads = torch.get_num_threads()
    _pkg_resources_shim()
    try:
        import yolov5
        from yolov5.models.yolo import Model
    except ImportError as err:
        return None, f"the reference YOLOv5s is left out: yolov5 does not import ({err}; {INSTALL})"
    finally:
        cv2.setNumThreads(cv_threads)
        torch.set_num_threads(torch_threads)
    for name in ("yolov5", "ultralytics"):  # their import sets up loggers that print every layer built
        logging.getLogger(name).setLevel(logging.ERROR)
    yaml = Path(yolov5.__file__).parent / "models" / "yolov5s.yaml"
    torch.manual_seed(0)
    model = Model(str(yaml), ch=3, nc=num_classes).fuse().eval()
    version = getattr(yolov5, "__version__", "?")
    return model, f"yolov5 {version} (ultralytics v7.0) YOLOv5s from {yaml.name}, random init, fused"
