"""The appearance encoder the tracker uses: a frame and its detection boxes -> L2-normalised features."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from spacetrack.device import resolve_device
from spacetrack.onnx_backend import check_backend, onnx_session
from spacetrack.reid.crops import Cropper, check_boxes, check_frame, frame_tensor
from spacetrack.reid.network import ReidNet

WEIGHTS_ARTIFACT = "weights/reid.pt"


def onnx_input_shape(net: ReidNet) -> tuple[int, int, int, int]:
    """The input shape the onnxruntime backend exports the network for; its first axis (crops) is left
    free (`dynamic_batch`)."""
    return (1, 3, net.input_height, net.input_width)


class Encoder:
    """`encoder(frame_rgb, boxes_tlwh)` -> (N, feature_dim) float32 unit vectors, one per box; no box gives
    (0, feature_dim). Crops are cut and encoded in batches of `batch_size` on `device` ("auto": CUDA when present).

    A box partly outside the frame is encoded with black beyond the border (see `Cropper`); a box wholly
    outside shows nothing of the target, so its row is all zeros: cosine distance 1 to every feature, it can
    never match by appearance.

    backend: "torch", or "onnxruntime": the network exported once to ONNX (any batch size) and run by ONNX
        Runtime on crops cut by torch on `device`.
    threads: ONNX Runtime intra-op threads (0: its default, one per physical core).
    onnx_dir: folder of the cached ONNX exports (None: `outputs/onnx/` in the repository).
    """

    def __init__(
        self,
        net: ReidNet,
        cropper: Cropper,
        *,
        device: str | torch.device = "auto",
        batch_size: int = 64,
        backend: str = "torch",
        threads: int = 0,
        onnx_dir: str | Path | None = None,
    ) -> None:
        if batch_size < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        if (cropper.height, cropper.width) != (net.input_height, net.input_width):
            raise ValueError(
                f"cropper makes {cropper.height}x{cropper.width} crops, the network takes "
                f"{net.input_height}x{net.input_width}"
            )
        self.device = resolve_device(device)
        self.backend = check_backend(backend, self.device.type)
        self.net = net.eval()
        self.session = None
        if self.backend == "onnxruntime":
            self.session = onnx_session(
                self.net,
                onnx_input_shape(net),
                threads=threads,
                device=self.device.type,
                dynamic_batch=True,
                cache_dir=onnx_dir,
                name="reid",
            )
        else:
            self.net.to(self.device)
        self.cropper, self.batch_size = cropper, batch_size

    @property
    def feature_dim(self) -> int:
        return self.net.feature_dim

    @classmethod
    def from_weights(cls, weights: str | Path, **kwargs) -> Encoder:
        """An encoder from a weights file written by training (`spacetrack.reid.weights.save_weights`);
        `conf/reid/table1.yaml` holds the keyword arguments of the pipeline's."""
        from spacetrack.reid.weights import load_weights

        net, cropper = load_weights(weights)
        return cls(net, cropper, **kwargs)

    @classmethod
    def from_mlflow(
        cls, run_id: str, *, artifact_path: str = WEIGHTS_ARTIFACT, tracking_uri: str | None = None, **kwargs
    ) -> Encoder:
        """An encoder from the weights a training run logged to MLflow (artifact `weights/reid.pt`)."""
        from spacetrack.mlflow_log import artifact_file
        from spacetrack.mlflow_log import tracking_uri as resolve_uri

        local = artifact_file(run_id, artifact_path, tracking_uri=resolve_uri(tracking_uri))
        return cls.from_weights(local, **kwargs)

    @torch.no_grad()
    def __call__(self, frame_rgb: np.ndarray, boxes_tlwh: np.ndarray | list) -> np.ndarray:
        """Features of the boxes (`tlwh`, pixels) in the RGB uint8 (H, W, 3) frame, (N, feature_dim) float32."""
        boxes = check_boxes(boxes_tlwh)
        check_frame(frame_rgb)
        height, width = frame_rgb.shape[:2]
        seen = np.flatnonzero(
            (boxes[:, 0] < width)
            & (boxes[:, 1] < height)
            & (boxes[:, 0] + boxes[:, 2] > 0)
            & (boxes[:, 1] + boxes[:, 3] > 0)
        )
        out = np.zeros((len(boxes), self.feature_dim), dtype=np.float32)
        if not len(seen):
            return out
        # Only the part of the frame the crops sample (one pixel more for bilinear neighbours) is converted
        # to float: on the CPU converting a whole 640x480 frame costs more than cutting a few crops.
        regions = self.cropper.sampling_boxes(boxes[seen])
        x0, y0 = (max(int(np.floor(regions[:, i].min())) - 1, 0) for i in (0, 1))
        x1 = min(int(np.ceil(regions[:, 2].max())) + 1, width)
        y1 = min(int(np.ceil(regions[:, 3].max())) + 1, height)
        frame = frame_tensor(frame_rgb[y0:y1, x0:x1], self.device)
        shifted = boxes - np.array([x0, y0, 0.0, 0.0])
        for start in range(0, len(seen), self.batch_size):
            rows = seen[start : start + self.batch_size]
            out[rows] = self.features(self.cropper(frame, shifted[rows]))
        return out

    @torch.no_grad()
    def features(self, crops: torch.Tensor) -> np.ndarray:
        """Features of one batch of (N, 3, H, W) crops in [0, 1], (N, feature_dim) float32."""
        if self.session is not None:
            return self.session(crops.cpu().numpy())[0]
        return self.net(crops.to(self.device)).float().cpu().numpy()

    @torch.no_grad()
    def encode_crops(self, crops: torch.Tensor) -> np.ndarray:
        """Features of ready (N, 3, H, W) crops in [0, 1], in batches; (N, feature_dim) float32."""
        out = [self.features(crops[i : i + self.batch_size]) for i in range(0, len(crops), self.batch_size)]
        return np.concatenate(out) if out else np.zeros((0, self.feature_dim), dtype=np.float32)
