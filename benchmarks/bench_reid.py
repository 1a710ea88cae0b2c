"""Time the re-ID encoder per crop at batch 1 and batch 32 (CPU, and GPU when present).

Contenders, timed in the same run on the same 640x480 frame and boxes (random weights: the time does not
depend on their values):
- `encoder`: `spacetrack.reid.Encoder` end to end, boxes -> roi_align crops -> Table 1 network -> features;
- `opencv_crops` (the peer for cutting crops): the classical per-box path, slice the frame, pad what lies
  beyond it, cv2.resize to 64x128, stack and convert, then the same network;
- `crops_only` / `opencv_crops_only`: the two crop paths without the network;
- `network_only`: the network on ready crops, so users see where the time goes;
- `encoder_onnxruntime` / `network_only_onnxruntime`: the same with the network run by ONNX Runtime
  (`reid.backend=onnxruntime`) on as many threads as torch.

Contenders alternate call by call, so that load from other processes hits them alike.

    python benchmarks/bench_reid.py [--repeats 20] [--device cpu|cuda] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import tempfile

import cv2
import numpy as np
import torch

from common import interleaved_samples, markdown_table, summarize, write_report
from spacetrack.reid import Cropper, Encoder, ReidNet
from spacetrack.reid.crops import frame_tensor

WIDTH, HEIGHT = 640, 480


def scene(num_boxes: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A noisy dark frame and `num_boxes` tlwh boxes of 10-120 px, some crossing the border."""
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 40, (HEIGHT, WIDTH, 3), dtype=np.uint8)
    size = rng.uniform(10, 120, (num_boxes, 2))
    top_left = rng.uniform(-20, [WIDTH - 10, HEIGHT - 10], (num_boxes, 2))
    return frame, np.concatenate([top_left, size], axis=1)


def opencv_crops(frame: np.ndarray, boxes: np.ndarray, cropper: Cropper) -> torch.Tensor:
    """The per-box OpenCV peer: the same sampling boxes, cut by slicing and padding, resized one by one."""
    crops = []
    for x0, y0, x1, y1 in np.round(cropper.sampling_boxes(boxes)).astype(int):
        patch = np.zeros((max(y1 - y0, 1), max(x1 - x0, 1), 3), np.uint8)
        sx0, sy0, sx1, sy1 = max(x0, 0), max(y0, 0), min(x1, WIDTH), min(y1, HEIGHT)
        if sx1 > sx0 and sy1 > sy0:
            patch[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = frame[sy0:sy1, sx0:sx1]
        crops.append(cv2.resize(patch, (cropper.width, cropper.height), interpolation=cv2.INTER_AREA))
    return torch.from_numpy(np.stack(crops)).permute(0, 3, 1, 2).float().div(255.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's)")
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)
    torch.manual_seed(0)
    cropper = Cropper()
    net = ReidNet()
    encoder = Encoder(net, cropper, device=device, batch_size=64)
    onnx_dir = tempfile.TemporaryDirectory()
    by_ort = Encoder(net, cropper, device=device, batch_size=64, backend="onnxruntime",
                     threads=args.threads or 0, onnx_dir=onnx_dir.name)  # fmt: skip
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)

    def timed(fn):
        def call():
            fn()
            sync()

        return call

    results, rows = {}, []
    load_before = os.getloadavg()
    for batch in (1, 32):
        frame, boxes = scene(batch)
        ready = cropper(frame_tensor(frame, device), boxes)
        calls = {
            "encoder": lambda f=frame, b=boxes: encoder(f, b),
            "opencv_crops": lambda f=frame, b=boxes: encoder.encode_crops(opencv_crops(f, b, cropper)),
            "crops_only": lambda f=frame, b=boxes: cropper(frame_tensor(f, device), b),
            "opencv_crops_only": lambda f=frame, b=boxes: opencv_crops(f, b, cropper).to(device),
            "network_only": lambda r=ready: encoder.encode_crops(r),
            "encoder_onnxruntime": lambda f=frame, b=boxes: by_ort(f, b),
            "network_only_onnxruntime": lambda r=ready: by_ort.encode_crops(r),
        }
        wall, _ = interleaved_samples({name: timed(fn) for name, fn in calls.items()}, repeats=args.repeats)
        stats = {name: summarize(samples) for name, samples in wall.items()}
        peer = stats["opencv_crops"]["median"]
        for name, s in stats.items():
            per_crop = s["median"] / batch
            results[f"{name}_batch{batch}"] = {
                **s,
                "batch": batch,
                "ms_per_crop": per_crop,
                "ratio_to_opencv_crops": s["median"] / peer,
            }
            rows.append([name, batch, s["median"], per_crop, s["p25"], s["p75"], s["median"] / peer])
    record = {
        "what": "re-ID encoder, 640x480 RGB frame, tlwh boxes 10-120 px -> 128-d unit features (ms)",
        "device": str(device),
        "torch_threads": torch.get_num_threads(),
        "onnxruntime_threads": args.threads or 0,
        "repeats": args.repeats,
        "load_average_1_5_15min": {"before": list(load_before), "after": list(os.getloadavg())},
        "results": results,
    }
    onnx_dir.cleanup()
    header = ["contender", "batch", "median ms", "ms per crop", "p25", "p75", "x opencv_crops"]
    table = (
        f"# Re-ID encoder ({device}, {torch.get_num_threads()} torch thread(s))\n\n"
        f"1-minute load average {load_before[0]:.1f} before, {os.getloadavg()[0]:.1f} after the run, on a "
        f"machine shared with other jobs: compare ratios within the run.\n\n" + markdown_table(header, rows)
    )
    json_path, _ = write_report("reid", record, table)
    print(table)
    print(f"wrote {json_path}")


if __name__ == "__main__":
    main()
