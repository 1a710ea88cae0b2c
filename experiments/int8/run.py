"""INT8 against float32: mAP@0.5 of the detector's backends on a fold its weights never saw, and speed.

The weights (default: the shipped `weights/detector_yolov5s_fold3.pt`, trained with fold 3 held out) are
scored on every `--frame-stride`-th frame of their validation fold's sequences at native resolution
(640x480), as `experiments/detector_cv/` scores them: NMS at score >= 0.001, IoU 0.6, 300 boxes. The
contenders are the pipeline's backends (`detector.backend`): torch (the Conv+BN fused copy), onnxruntime
(float32, what `auto` runs on a CPU) and onnxruntime_int8 with each calibration method asked for, calibrated
on frames of the other eight folds. The milliseconds per frame are those of the scoring pass (batch 1,
`--threads` threads), on a machine shared with other jobs: a rough guide, the benchmarks time properly.

    python experiments/int8/run.py                                  # -> experiments/int8/results.json
    python experiments/int8/run.py --methods minmax entropy --frames 64 128
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path
from types import SimpleNamespace

import torch
from hydra.utils import instantiate
from torch import nn
from torch.utils.data import DataLoader

from spacetrack.config import REPO_ROOT
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.data.yolo_dataset import YoloDataset, collate, image_source
from spacetrack.engine.checkpoint import load_checkpoint
from spacetrack.engine.validate import evaluate
from spacetrack.io import atomic_write_text, file_hash
from spacetrack.pipeline.detector import YoloDetector
from spacetrack.quantize import METHODS

HERE = Path(__file__).resolve().parent
SHIPPED = REPO_ROOT / "weights" / "detector_yolov5s_fold3.pt"
METRICS = ("map50", "map50_95", "precision", "recall", "recall_at_score")


class BackendModel(nn.Module):
    """A YoloDetector's network as `evaluate` calls a model: forward gives the decoded boxes (one image at
    a time, as the pipeline runs it), and `detect.decode` passes them on; forward's seconds are kept."""

    def __init__(self, detector: YoloDetector) -> None:
        super().__init__()
        self.detector = detector
        self.detect = SimpleNamespace(decode=lambda p: p)
        self.seconds: list[float] = []

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = []
        for image in x:
            start = time.perf_counter()
            if self.detector.network is None:
                session = self.detector.session(*image.shape[1:])
                out.append(torch.from_numpy(session(image[None].numpy())[0]))
            else:
                with torch.inference_mode():
                    out.append(
                        self.detector.network.predict(
                            image[None].contiguous(memory_format=torch.channels_last)
                        )
                    )
            self.seconds.append(time.perf_counter() - start)
        return torch.cat(out)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--weights", default=str(SHIPPED))
    parser.add_argument(
        "--data", default=None, help="dataset folder (default: the checkpoint's, under data/)"
    )
    parser.add_argument("--frame-stride", type=int, default=2)
    parser.add_argument("--methods", nargs="+", choices=METHODS, default=["minmax", "percentile"])
    parser.add_argument("--frames", type=int, nargs="+", default=[64], help="calibration frame counts")
    parser.add_argument("--no-torch", action="store_true", help="leave out the torch contender (slowest)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--out", default=str(HERE / "results.json"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    settings = load_checkpoint(args.weights).get("settings") or {}
    root = Path(args.data) if args.data else REPO_ROOT / "data" / settings["data"]["name"]
    fold = settings.get("fold")
    if fold is None:
        raise ValueError(f"{args.weights} records no validation fold: nothing is held out to score it on")
    manifest = load_manifest(root)
    _, val_names = split_sequences(manifest, fold)
    enhancer = instantiate(settings.get("enhance") or {"_target_": "spacetrack.enhance.NoEnhancement"})
    image_dir, on_the_fly = image_source(root, val_names, enhancer.name)
    store = FrameStore(root=root, image_dir=image_dir, enhancer=enhancer if on_the_fly else None,
                       enhancer_name=enhancer.name)  # fmt: skip
    data = YoloDataset(root=root, sequences=val_names, num_classes=len(manifest["class_names"]),
                       store=store, frame_stride=args.frame_stride)  # fmt: skip
    common = {"weights": args.weights, "device": "cpu", "threads": args.threads}
    contenders = {} if args.no_torch else {"torch": {"backend": "torch"}}
    contenders["onnxruntime"] = {"backend": "onnxruntime"}
    for method in args.methods:
        for frames in args.frames:
            contenders[f"onnxruntime_int8 {method} {frames}"] = {
                "backend": "onnxruntime_int8", "calibration_data": args.data,
                "calibration_method": method, "calibration_frames": frames,
            }  # fmt: skip
    results = {}
    for name, kwargs in contenders.items():
        model = BackendModel(YoloDetector(**common, **kwargs))
        loader = DataLoader(data, batch_size=4, collate_fn=collate)
        metrics, _ = evaluate(model, loader, device=torch.device("cpu"), conf_threshold=0.001,
                              iou_threshold=0.6, max_det=300)  # fmt: skip
        ms = sorted(1e3 * s for s in model.seconds)
        results[name] = {**{k: metrics[k] for k in METRICS}, "ms_per_frame_median": ms[len(ms) // 2],
                         **kwargs}  # fmt: skip
        print(name, json.dumps(results[name]), flush=True)
    reference = results["onnxruntime"]["map50"]
    for record in results.values():
        record["map50_loss_vs_float32"] = reference - record["map50"]
    out = {
        "weights": Path(args.weights).name,
        "weights_hash": file_hash(args.weights),
        "dataset": manifest["name"],
        "held_out_fold": fold,
        "sequences": val_names,
        "frames_scored": len(data),
        "frame_stride": args.frame_stride,
        "threads": args.threads,
        "load_average_1min": os.getloadavg()[0],
        "results": results,
    }
    atomic_write_text(args.out, json.dumps(out, indent=2) + "\n")
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
