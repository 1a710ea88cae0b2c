"""Detectors the pipeline runs per frame: the trained YOLOv5s(+GAM), or ground truth as a stand-in.

Both are callables `detector(rgb, frame) -> (N, 6)` rows `x, y, w, h, score, class` (box `tlwh` in pixels
of the frame, 1-based `frame`), with `begin(source)` called before each sequence and `identity`, a string
that changes whenever the detections would (weights hash, settings), for the detection cache.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import torch
from torch import nn

from spacetrack.data.layout import BOX, CLASS, CONF, FRAME, read_mot
from spacetrack.device import resolve_device
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.inference import (
    TTA_VIEWS,
    augmented_predictions,
    check_image_size,
    frame_detections,
    network_input,
    tta_views,
)
from spacetrack.engine.nms import check_score
from spacetrack.engine.precision import native_bfloat16
from spacetrack.io import file_hash
from spacetrack.models.yolo import YOLOv5, fuse_for_inference
from spacetrack.onnx_backend import DETECTOR_BACKENDS, MethodModule, OrtSession, check_backend, onnx_session
from spacetrack.pipeline.sources import FrameSource
from spacetrack.quantize import Calibration, quantized_onnx, training_frames
from spacetrack.tracking.preprocessing import non_max_suppression

ONNX_BACKENDS = ("onnxruntime", "onnxruntime_int8")
# Channels-last memory layout for the torch backend on the CPU: oneDNN's convolutions then skip the
# layout reorders around each layer (see docs/speed.md for the measurement).
CHANNELS_LAST_CPU = True


def onnx_graph(model: YOLOv5, height: int, width: int | None = None) -> tuple[nn.Module, tuple[int, ...]]:
    """What the onnxruntime backend exports: the network with its box decoding (`predict`), and its input
    shape, one RGB image of height x width pixels (square when `width` is None)."""
    return MethodModule(model, "predict"), (1, 3, height, width or height)


def check_bfloat16(device: torch.device) -> None:
    """A ValueError when `device` has no native bfloat16 (backend torch_bf16 would only be slower)."""
    if device.type == "cuda":
        supported = torch.cuda.is_bf16_supported()
    else:
        supported = device.type == "cpu" and native_bfloat16()
    if not supported:
        needs = "AVX512-BF16 or AMX" if device.type == "cpu" else "an Ampere or newer GPU"
        raise ValueError(
            f"backend torch_bf16 needs native bfloat16 ({needs}); this {device.type} has none "
            "(autocast would emulate it, slower than float32): use backend=torch or onnxruntime"
        )


def inference_network(model: YOLOv5, device: torch.device) -> YOLOv5:
    """The torch backend's copy of `model`: Conv+BN fused, on `device`, channels-last on the CPU."""
    network = fuse_for_inference(model).to(device)
    if device.type == "cpu" and CHANNELS_LAST_CPU:
        network = network.to(memory_format=torch.channels_last)
    return network


class CalibrationInputs:
    """RGB frames as network inputs of one shape, prepared on access (a sequence for `quantized_onnx`)."""

    def __init__(self, frames: list[np.ndarray], image_size: int | None, shape: tuple[int, int]) -> None:
        self.frames, self.image_size, self.shape = frames, image_size, shape

    def __len__(self) -> int:
        return len(self.frames)

    def __getitem__(self, i: int) -> np.ndarray:
        boxed = network_input(self.frames[i], self.image_size)[0]
        height, width = self.shape
        if boxed.shape[:2] != (height, width):
            boxed = cv2.resize(boxed, (width, height), interpolation=cv2.INTER_LINEAR)
        return boxed.transpose(2, 0, 1)[None].astype(np.float32) / np.float32(255)


class YoloDetector:
    """A trained detector checkpoint on RGB frames: the frame at native size, predict, torchvision NMS.

    weights: a `best.pt` written by `python -m spacetrack.train`.
    image_size: None (the default): each frame at its native resolution, padded to a multiple of 32 (how
        the detector is validated); an integer letterboxes it to that square (faster, loses small
        targets).
    conf_threshold: detections scoring below this are dropped (keep it below the tracker's
        `min_confidence`, so that the cache serves every tracker setting).
    iou_threshold: NMS IoU limit between boxes of one class (of any class with `agnostic_nms`).
    agnostic_nms: NMS over every class at once: a target the network names two ways (a rocket body seen
        end-on is a disc, like debris) keeps one box instead of two, which the tracker, following every
        class alike, would take for two targets. False: per class (YOLOv5's, how the mAP is measured).
    part_overlap: after NMS, a box lying at least this share inside a higher-scored box of any class is
        taken for a part of that object (a lit panel of a dim satellite, boxed on its own) and dropped:
        DeepSORT's own NMS rule (intersection over the lower-scored box's area), which IoU NMS misses
        when the part is small. None: none.
    score: what a detection's score is, the number the tracker's `min_confidence` compares: "class"
        (objectness times the best class probability, YOLOv5's, the default) or "objectness" (objectness
        alone: whether there is a target, however the model splits it between the classes, which the
        tracker does not tell apart).
    tta: test-time augmentation: True: the network also sees each frame at 0.83 of its size mirrored and
        at 0.67 of its size (YOLOv5's views, `inference.TTA_VIEWS`), and every view's boxes go to one NMS:
        three passes a frame instead of one, for more of the dim and glaring targets. A list of
        `[scale, mirrored]` pairs gives the views instead (`[[1.0, false], [1.5, false]]`: the frame as
        it is and enlarged by half); a third number in a view keeps only its boxes whose longer side is
        at most that many input pixels (`[1.5, false, 32]`: the enlarged view for small targets only).
        False: one pass. Any backend.
    device: "auto" (CUDA when present), "cpu" or "cuda".
    backend: how the network runs; letterbox and NMS are the same for all.
        "torch": a copy with Conv+BN fused, under `inference_mode`, channels-last on the CPU.
        "torch_bf16": the same under bfloat16 autocast; only where the device computes bfloat16 natively
            (a ValueError otherwise).
        "onnxruntime": the network (with its box decoding) exported once to ONNX and run by ONNX Runtime.
        "onnxruntime_int8": that graph quantised to INT8 (`spacetrack.quantize`), calibrated on frames of
            the detector's own training sequences; cached beside the float export.
        "auto": onnxruntime (float32) on the CPU, torch on CUDA.
    threads: ONNX Runtime intra-op threads (0: its default, one per physical core); torch's threads are
        the pipeline's `threads` key.
    onnx_dir: folder of the cached ONNX exports and quantised graphs (None: `outputs/onnx/`).
    calibration_data: the INT8 backend's calibration dataset folder (None: `data/<the dataset the
        checkpoint was trained on>`); its sequences outside the checkpoint's validation fold are used.
    calibration_frames, calibration_method: how many calibration frames, and how activation ranges are
        set from them ("minmax", "entropy" or "percentile"; see `quantize.Calibration`).
    """

    def __init__(
        self,
        *,
        weights: str | Path,
        image_size: int | None = None,
        conf_threshold: float = 0.1,
        iou_threshold: float = 0.45,
        max_det: int = 100,
        score: str = "class",
        agnostic_nms: bool = False,
        part_overlap: float | None = None,
        tta: bool = False,
        device: str = "auto",
        backend: str = "torch",
        threads: int = 0,
        onnx_dir: str | Path | None = None,
        calibration_data: str | Path | None = None,
        calibration_frames: int = 64,
        calibration_method: str = "minmax",
    ) -> None:
        check_image_size(image_size)
        check_score(score, "detector.score")
        self.device = resolve_device(device)
        self.backend = check_backend(backend, self.device.type, DETECTOR_BACKENDS)
        if self.backend == "torch_bf16":
            check_bfloat16(self.device)
        if self.backend == "onnxruntime_int8" and self.device.type != "cpu":
            raise ValueError(f"backend onnxruntime_int8 runs on the CPU, got device={device!r}")
        self.weights = Path(weights)
        self.model = load_detector(weights)
        self.calibration = Calibration(frames=calibration_frames, method=calibration_method)
        self.calibration_data = calibration_data
        self._sessions: dict[tuple[int, int], OrtSession] = {}
        self._onnx = {"threads": threads, "device": self.device.type, "cache_dir": onnx_dir}
        self.network = None if self.backend in ONNX_BACKENDS else inference_network(self.model, self.device)
        self._channels_last = self.network is not None and self.device.type == "cpu" and CHANNELS_LAST_CPU
        self.image_size, self.conf_threshold = image_size, conf_threshold
        self.iou_threshold, self.max_det, self.score = iou_threshold, max_det, score
        self.agnostic_nms = bool(agnostic_nms)
        if part_overlap is not None and not 0.0 < part_overlap <= 1.0:
            raise ValueError(f"detector.part_overlap must lie in (0, 1] or be null, got {part_overlap}")
        self.part_overlap = part_overlap
        self.tta = tta_views(tta)
        self.identity = (
            f"yolo {file_hash(weights)} size={image_size or 'native'} conf={conf_threshold} "
            f"iou={iou_threshold} backend={self.backend}"
        )
        if score != "class":  # the default leaves the identity, and so the caches made before, as they were
            self.identity += f" score={score}"
        if self.agnostic_nms:
            self.identity += " nms=agnostic"
        if part_overlap is not None:
            self.identity += f" part_overlap={part_overlap}"
        if self.tta == TTA_VIEWS:
            self.identity += " tta"
        elif self.tta:
            self.identity += " tta=" + ",".join(
                f"{scale:g}{'m' if mirrored else ''}{''.join(f'<{m:g}' for m in limit)}"
                for scale, mirrored, *limit in self.tta
            )
        if self.backend == "onnxruntime_int8":
            self.identity += f" calibration={self.calibration}"

    def session(self, height: int, width: int) -> OrtSession:
        """The ONNX Runtime session for inputs of height x width pixels (exported, and for the INT8
        backend quantised, on first use)."""
        if (height, width) not in self._sessions:
            session = onnx_session(
                *onnx_graph(self.model, height, width), name=f"yolo{height}x{width}", **self._onnx
            )
            if self.backend == "onnxruntime_int8":
                path = quantized_onnx(
                    session.path, self.calibration_inputs(height, width), self.calibration, self._described()
                )
                session = OrtSession(path, threads=self._onnx["threads"])
            self._sessions[height, width] = session
        return self._sessions[height, width]

    def _described(self) -> dict:
        if not hasattr(self, "_calibration_frames"):
            self._calibration_frames = training_frames(
                self.weights, self.calibration.frames, self.calibration_data
            )
        return self._calibration_frames[1]

    def calibration_inputs(self, height: int, width: int) -> CalibrationInputs:
        """The calibration frames as network inputs (1, 3, height, width) float32, each prepared on access
        as the detector would prepare it (resized when its size gives another input shape)."""
        self._described()
        return CalibrationInputs(self._calibration_frames[0], self.image_size, (height, width))

    def begin(self, source: FrameSource) -> None:
        """Nothing to prepare: a detector sees each frame alone."""

    @torch.inference_mode()
    def predict(self, boxed: np.ndarray) -> torch.Tensor:
        """Decoded predictions (1, N, 5 + classes) float32 of one network-input RGB uint8 image (with
        `tta`, of each of its views, together)."""
        x = torch.from_numpy(boxed).to(self.device).permute(2, 0, 1)[None].float().div_(255)
        return augmented_predictions(self._predict, x, self.tta) if self.tta else self._predict(x)

    def _predict(self, x: torch.Tensor) -> torch.Tensor:
        """Decoded predictions of a float (1, 3, H, W) input in [0, 1], by the backend."""
        if self.backend in ONNX_BACKENDS:
            x = x.cpu().numpy()
            return torch.from_numpy(self.session(*x.shape[2:])(np.ascontiguousarray(x))[0])
        if self._channels_last:
            x = x.contiguous(memory_format=torch.channels_last)
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.backend == "torch_bf16"):
            return self.network.predict(x)

    @torch.inference_mode()
    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        prepared = network_input(rgb, self.image_size)
        (det,) = frame_detections(
            self.predict(prepared[0]),
            [prepared],
            [rgb.shape],
            conf_threshold=self.conf_threshold,
            iou_threshold=self.iou_threshold,
            max_det=self.max_det,
            score=self.score,
            agnostic=self.agnostic_nms,
        )
        boxes = np.column_stack([det[:, :2], det[:, 2:4] - det[:, :2], det[:, 4:6]])
        if self.part_overlap is not None:
            boxes = boxes[np.sort(non_max_suppression(boxes[:, :4], boxes[:, 4], self.part_overlap))]
        return boxes


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

    @staticmethod
    def truth_files(root: str | Path, sequence: str) -> tuple[Path, Path]:
        """The files its boxes of `sequence` come from: moving targets, then static objects (optional)."""
        folder = Path(root) / sequence / "gt"
        return folder / "gt.txt", folder / "static.txt"

    def begin(self, source: FrameSource) -> None:
        moving, static = self.truth_files(self.root, source.name)
        if not moving.is_file():
            raise FileNotFoundError(
                f"detector=ground_truth needs {moving}: source {source.description} is not a "
                f"sequence of dataset {self.root}"
            )
        rows = [read_mot(moving)]
        if static.is_file():
            rows.append(read_mot(static))
        table = np.concatenate(rows)
        self._rows = table[table[:, CONF] > 0]

    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        rows = self._rows[self._rows[:, FRAME] == frame]
        return np.column_stack([rows[:, BOX], np.full(len(rows), self.score), rows[:, CLASS]])
