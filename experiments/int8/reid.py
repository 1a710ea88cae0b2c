"""Does INT8 pay for the re-ID network? Features and time of the Table 1 network, float32 against INT8.

The shipped `weights/reid_fold3.pt` exported to ONNX as the pipeline's `reid.backend=onnxruntime` runs
it, then statically quantised by ONNX Runtime (QDQ, int8 weights per output channel, uint8 activations
per tensor, min-max ranges) on 64 crops of the eight training folds. Scored on crops of fold 3's moving
targets (every 10th frame): the cosine distance between each crop's float32 and INT8 features (the
quantity DeepSORT gates at `max_cosine_distance`, 0.1 in the paper), and ONNX Runtime's median time of
both graphs at batch 1 and 4 on one thread, interleaved call by call.

    python experiments/int8/reid.py        # -> experiments/int8/reid.json
"""

from __future__ import annotations

import json
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

from spacetrack.config import REPO_ROOT
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.io import atomic_write_text
from spacetrack.onnx_backend import INPUT_NAME, OrtSession
from spacetrack.reid import Encoder
from spacetrack.reid.dataset import collect_crops, cut_crops

HERE = Path(__file__).resolve().parent
ROOT = REPO_ROOT / "data" / "space_default"
WEIGHTS = REPO_ROOT / "weights" / "reid_fold3.pt"
FOLD = 3
CALIBRATION_CROPS = 64
ROUNDS = 30


class Crops(CalibrationDataReader):
    def __init__(self, inputs: list[np.ndarray]) -> None:
        self.inputs = iter(inputs)

    def get_next(self) -> dict | None:
        x = next(self.inputs, None)
        return None if x is None else {INPUT_NAME: x}


def network_input(crops: np.ndarray) -> np.ndarray:
    return torch.from_numpy(crops).permute(0, 3, 1, 2).float().div(255).numpy()


def unit(features: np.ndarray) -> np.ndarray:
    return features / np.linalg.norm(features, axis=1, keepdims=True)


def main() -> None:
    encoder = Encoder.from_weights(WEIGHTS, device="cpu", backend="onnxruntime", threads=1)
    train, val = split_sequences(load_manifest(ROOT), FOLD)
    rows = {"min_visibility": 0.3, "min_box_size": 4.0}
    pool = cut_crops(
        ROOT, collect_crops(ROOT, train, include_static=True, frame_stride=50, **rows), encoder.cropper
    )
    held_out = cut_crops(ROOT, collect_crops(ROOT, val, include_static=False, frame_stride=10, **rows),
                         encoder.cropper)  # fmt: skip
    pick = np.random.default_rng(0).choice(len(pool), CALIBRATION_CROPS, replace=False)
    calibration = [network_input(pool[i : i + 1]) for i in pick]
    with tempfile.TemporaryDirectory() as scratch:
        int8_path = Path(scratch) / "reid-int8.onnx"
        quantize_static(str(encoder.session.path), str(int8_path), Crops(calibration), quant_format=QuantFormat.QDQ,
                        per_channel=True, activation_type=QuantType.QUInt8, weight_type=QuantType.QInt8)  # fmt: skip
        graphs = {
            "float32": OrtSession(encoder.session.path, threads=1),
            "int8": OrtSession(int8_path, threads=1),
        }
        x = network_input(held_out)
        features = {k: unit(np.concatenate([g(x[i : i + 32])[0] for i in range(0, len(x), 32)]))
                    for k, g in graphs.items()}  # fmt: skip
        distance = 1.0 - (features["float32"] * features["int8"]).sum(1)
        timing = {}
        for batch in (1, 4):
            samples = {k: [] for k in graphs}
            for _ in range(3):
                for g in graphs.values():
                    g(x[:batch])
            for _ in range(ROUNDS):
                for k, g in graphs.items():
                    started = time.perf_counter()
                    g(x[:batch])
                    samples[k].append(time.perf_counter() - started)
            ms = {k: 1e3 * statistics.median(v) for k, v in samples.items()}
            timing[f"batch {batch}"] = {
                **{f"{k}_ms": v for k, v in ms.items()},
                "ratio": ms["int8"] / ms["float32"],
            }
    result = {
        "weights": WEIGHTS.name,
        "held_out_crops": len(held_out),
        "calibration_crops": CALIBRATION_CROPS,
        "cosine_distance_float32_int8": {
            "median": float(np.median(distance)),
            "p95": float(np.percentile(distance, 95)),
            "max": float(distance.max()),
            "share_above_0.05": float((distance > 0.05).mean()),
        },
        "onnxruntime_1_thread": timing,
    }
    atomic_write_text(HERE / "reid.json", json.dumps(result, indent=2) + "\n")
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
