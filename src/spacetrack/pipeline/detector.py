"""Detectors the pipeline runs per frame: the trained YOLOv5s(+GAM), or ground truth as a stand-in.

Both are callables `detector(rgb, frame) -> (N, 6)` rows `x, y, w, h, score, class` (box `tlwh` in pixels
of the frame, 1-based `frame`), with `begin(source)` called before each sequence and `identity`, a string
that changes whenever the detections would (weights hash, settings), for the detection cache.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from spacetrack.data.layout import BOX, CLASS, CONF, FRAME, read_mot
from spacetrack.device import resolve_device
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.inference import check_image_size, frame_detections, network_input
from spacetrack.io import file_hash
from spacetrack.models.yolo import YOLOv5
from spacetrack.onnx_backend import MethodModule, check_backend, onnx_session
from spacetrack.pipeline.sources import FrameSource


def onnx_graph(model: YOLOv5, height: int, width: int | None = None) -> tuple[nn.Module, tuple[int, ...]]:
    """What the onnxruntime backend exports: the network with its box decoding (`predict`), and its input
    shape, one RGB image of height x width pixels (square when `width` is None)."""
    return MethodModule(model, "predict"), (1, 3, height, width or height)


class YoloDetector:
    """A trained detector checkpoint on RGB frames: the frame at native size, predict, torchvision NMS.

    weights: a `best.pt` written by `python -m spacetrack.train`.
    image_size: None (the default): each frame at its native resolution, padded to a multiple of 32 (how
        the detector is validated); an integer letterboxes it to that square (faster, loses small
        targets).
    conf_threshold: detections scoring below this are dropped (keep it below the tracker's
        `min_confidence`, so that the cache serves every tracker setting).
    iou_threshold: NMS IoU limit between boxes of one class.
    device: "auto" (CUDA when present), "cpu" or "cuda".
    backend: "torch", or "onnxruntime": the network (with its box decoding) exported once to ONNX and run
        by ONNX Runtime; letterbox and NMS are the same for both. "auto": onnxruntime on the CPU, torch
        on CUDA.
    threads: ONNX Runtime intra-op threads (0: its default, one per physical core); torch's threads are
        the pipeline's `threads` key.
    onnx_dir: folder of the cached ONNX exports (None: `outputs/onnx/` in the repository).
    """

    def __init__(
        self,
        *,
        weights: str | Path,
        image_size: int | None = None,
        conf_threshold: float = 0.1,
        iou_threshold: float = 0.45,
        max_det: int = 100,
        device: str = "auto",
        backend: str = "torch",
        threads: int = 0,
        onnx_dir: str | Path | None = None,
    ) -> None:
        check_image_size(image_size)
        self.device = resolve_device(device)
        self.backend = check_backend(backend, self.device.type)
        self.model = load_detector(weights)
        self._sessions: dict[tuple[int, int], object] = {}
        self._onnx = {"threads": threads, "device": self.device.type, "cache_dir": onnx_dir}
        if self.backend != "onnxruntime":
            self.model.to(self.device)
        self.image_size, self.conf_threshold = image_size, conf_threshold
        self.iou_threshold, self.max_det = iou_threshold, max_det
        self.identity = (
            f"yolo {file_hash(weights)} size={image_size or 'native'} conf={conf_threshold} "
            f"iou={iou_threshold} backend={self.backend}"
        )

    def session(self, height: int, width: int):
        """The ONNX Runtime session for inputs of height x width pixels (exported on first use)."""
        if (height, width) not in self._sessions:
            self._sessions[height, width] = onnx_session(
                *onnx_graph(self.model, height, width), name=f"yolo{height}x{width}", **self._onnx
            )
        return self._sessions[height, width]

    def begin(self, source: FrameSource) -> None:
        """Nothing to prepare: a detector sees each frame alone."""

    @torch.no_grad()
    def predict(self, boxed: np.ndarray) -> torch.Tensor:
        """Decoded predictions (1, N, 5 + classes) float32 of one network-input RGB uint8 image."""
        if self.backend == "onnxruntime":
            x = boxed.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255)
            return torch.from_numpy(self.session(*boxed.shape[:2])(x)[0])
        x = torch.from_numpy(boxed).to(self.device).permute(2, 0, 1)[None].float().div_(255)
        return self.model.predict(x).float()

    @torch.no_grad()
    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        prepared = network_input(rgb, self.image_size)
        (det,) = frame_detections(
            self.predict(prepared[0]),
            [prepared],
            [rgb.shape],
            conf_threshold=self.conf_threshold,
            iou_threshold=self.iou_threshold,
            max_det=self.max_det,
        )
        return np.column_stack([det[:, :2], det[:, 2:4] - det[:, :2], det[:, 4:6]])


class GroundTruthDetector:
    """The dataset's own boxes as detections: every visible moving target (`gt/gt.txt`) and static object
    (`gt/static.txt`) with score `score`. An upper bound for the detector, and a network-free stand-in
    that checks the rest of the pipeline (motion filter, tracker, outputs) on rendered sequences.

    root: the dataset folder holding the sequences (`data/<name>`).
    """

    def __init__(self, *, root: str | Path, score: float = 1.0) -> None:
        self.root, self.score = Path(root), score
        self.identity = f"ground-truth {self.root.name} score={score}"
        self._rows = np.zeros((0, 9))

    def begin(self, source: FrameSource) -> None:
        folder = self.root / source.name / "gt"
        if not (folder / "gt.txt").is_file():
            raise FileNotFoundError(
                f"detector=ground_truth needs {folder / 'gt.txt'}: source {source.description} is not a "
                f"sequence of dataset {self.root}"
            )
        rows = [read_mot(folder / "gt.txt")]
        if (folder / "static.txt").is_file():
            rows.append(read_mot(folder / "static.txt"))
        table = np.concatenate(rows)
        self._rows = table[table[:, CONF] > 0]

    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        rows = self._rows[self._rows[:, FRAME] == frame]
        return np.column_stack([rows[:, BOX], np.full(len(rows), self.score), rows[:, CLASS]])
