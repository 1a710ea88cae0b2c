"""Detectors the pipeline runs per frame: the trained YOLOv5s(+GAM), or ground truth as a stand-in.

Both are callables `detector(rgb, frame) -> (N, 6)` rows `x, y, w, h, score, class` (box `tlwh` in pixels
of the frame, 1-based `frame`), with `begin(source)` called before each sequence and `identity`, a string
that changes whenever the detections would (weights hash, settings), for the detection cache.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import torch
from torch import nn

from spacetrack.data.layout import read_mot
from spacetrack.data.yolo_dataset import letterbox
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.nms import non_max_suppression
from spacetrack.models.yolo import YOLOv5
from spacetrack.onnx_backend import MethodModule, check_backend, onnx_session
from spacetrack.pipeline.sources import FrameSource


def file_hash(path: str | Path) -> str:
    """`sha256:<first 16 hex digits>` of a file's bytes: names a weights file whatever its path."""
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    return f"sha256:{digest[:16]}"


def resolve_device(name: str) -> torch.device:
    """ "auto" -> CUDA when present, else the CPU; anything else as torch names it."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def onnx_graph(model: YOLOv5, image_size: int) -> tuple[nn.Module, tuple[int, int, int, int]]:
    """What the onnxruntime backend exports: the network with its box decoding (`predict`), and its input
    shape, one RGB image of image_size x image_size pixels."""
    return MethodModule(model, "predict"), (1, 3, image_size, image_size)


class YoloDetector:
    """A trained detector checkpoint on RGB frames: letterbox to `image_size`, predict, torchvision NMS.

    weights: a `best.pt` written by `python -m spacetrack.train`.
    image_size: square letterbox side in pixels (a multiple of 32; smaller is faster, 320 is the CPU
        training size).
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
        image_size: int = 320,
        conf_threshold: float = 0.1,
        iou_threshold: float = 0.45,
        max_det: int = 100,
        device: str = "auto",
        backend: str = "torch",
        threads: int = 0,
        onnx_dir: str | Path | None = None,
    ) -> None:
        if image_size % 32:
            raise ValueError(f"image_size must be a multiple of 32 pixels, got {image_size}")
        self.device = resolve_device(device)
        self.backend = check_backend(backend, self.device.type)
        self.model = load_detector(weights)
        self.session = None
        if self.backend == "onnxruntime":
            self.session = onnx_session(
                *onnx_graph(self.model, image_size),
                threads=threads,
                device=self.device.type,
                cache_dir=onnx_dir,
                name=f"yolo{image_size}",
            )
        else:
            self.model.to(self.device)
        self.image_size, self.conf_threshold = image_size, conf_threshold
        self.iou_threshold, self.max_det = iou_threshold, max_det
        self.identity = (
            f"yolo {file_hash(weights)} size={image_size} conf={conf_threshold} iou={iou_threshold} "
            f"backend={self.backend}"
        )

    def begin(self, source: FrameSource) -> None:
        """Nothing to prepare: a detector sees each frame alone."""

    @torch.no_grad()
    def predict(self, boxed: np.ndarray) -> torch.Tensor:
        """Decoded predictions (1, N, 5 + classes) float32 of one letterboxed RGB uint8 image."""
        if self.session is not None:
            x = boxed.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255)
            return torch.from_numpy(self.session(x)[0])
        x = torch.from_numpy(boxed).to(self.device).permute(2, 0, 1)[None].float().div_(255)
        return self.model.predict(x).float()

    @torch.no_grad()
    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        boxed, scale, (pad_x, pad_y) = letterbox(rgb, self.image_size)
        (det,) = non_max_suppression(
            self.predict(boxed),
            conf_threshold=self.conf_threshold,
            iou_threshold=self.iou_threshold,
            max_det=self.max_det,
        )
        det = det.cpu().numpy().astype(np.float64)
        height, width = rgb.shape[:2]
        x1 = np.clip((det[:, 0] - pad_x) / scale, 0, width)
        y1 = np.clip((det[:, 1] - pad_y) / scale, 0, height)
        x2 = np.clip((det[:, 2] - pad_x) / scale, 0, width)
        y2 = np.clip((det[:, 3] - pad_y) / scale, 0, height)
        keep = (x2 > x1) & (y2 > y1)
        return np.column_stack([x1, y1, x2 - x1, y2 - y1, det[:, 4], det[:, 5]])[keep]


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
        self._rows = table[table[:, 6] > 0]

    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        rows = self._rows[self._rows[:, 0] == frame]
        return np.column_stack([rows[:, 2:6], np.full(len(rows), self.score), rows[:, 7]])
