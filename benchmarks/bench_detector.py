"""Detector speed: inference ms per image at 320 and 640 pixels, and training images per second.

Contenders: YOLOv5s (the peer), YOLOv5s + GAM and YOLOv5s + grouped GAM, timed in the same run. On the
CPU each is timed with torch and with ONNX Runtime (the pipeline's `detector.backend=onnxruntime`: the
same network exported to ONNX) at each thread count, the two backends alternating call by call so that
load from other processes hits both alike. Each inference time is also compared with its FLOP bound:
the model's multiply-adds (counted by torch's FLOP counter) divided by the rate this machine reaches
on a large matrix product with the same number of threads. On a GPU the same is measured with torch in
float32 and with AMP (bfloat16 autocast).

    python benchmarks/bench_detector.py [--threads 1 2] [--repeats 7] [--quick]
"""

from __future__ import annotations

import argparse
import itertools
import os
import tempfile
import time

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from common import interleaved_samples, markdown_table, progress, summarize, time_call, write_report
from spacetrack.engine.loss import YoloLoss
from spacetrack.engine.optim import build_optimizer
from spacetrack.models.yolo import YOLOv5, count_parameters
from spacetrack.onnx_backend import onnx_session
from spacetrack.pipeline.detector import onnx_graph

MODELS = {
    "yolov5s": {},
    "yolov5s_gam": {"gam_position": "after_sppf"},
    "yolov5s_gam_light": {"gam_position": "after_sppf", "gam_groups": 4},
}
NUM_CLASSES = 3


def forward_flops(model: torch.nn.Module, size: int) -> int:
    """Floating-point operations (2 per multiply-add) of one forward pass on a size x size image."""
    counter = FlopCounterMode(display=False)
    with counter, torch.no_grad():
        model(torch.zeros(1, 3, size, size))
    return counter.get_total_flops()


def peak_flops(device: torch.device, repeats: int) -> float:
    """FLOP/s of a 1024^3 float32 matrix product: the best rate dense convolution can hope for."""
    n = 1024
    a, b = torch.rand(n, n, device=device), torch.rand(n, n, device=device)
    samples = time_call(lambda: sync(device, a @ b), repeats=repeats)
    return 2 * n**3 / min(samples)


def sync(device: torch.device, value: object = None) -> object:
    if device.type == "cuda":
        torch.cuda.synchronize()
    return value


def torch_call(model, size, device, amp):
    """One batch-1 forward with box decoding (`predict`) on a random image, as a timed callable."""
    x = torch.rand(1, 3, size, size, device=device)

    def step():
        with torch.no_grad(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            model.predict(x)
        sync(device)

    return step


def onnxruntime_call(model, size, threads, folder):
    """The same forward by ONNX Runtime on `threads` intra-op threads (exported to `folder` first)."""
    session = onnx_session(*onnx_graph(model, size), threads=threads, cache_dir=folder)
    x = np.random.default_rng(0).random((1, 3, size, size), dtype=np.float32)
    return lambda: session(x)


def training_rate(model, size, batch, device, steps, amp) -> float:
    """Images per second of forward, loss, backward and SGD step on random images with one target each."""
    model.train()
    loss_fn = YoloLoss(
        anchors=model.detect.anchors, strides=model.stride, num_classes=NUM_CLASSES, image_size=size
    )
    optimizer = build_optimizer(model, lr0=0.01, momentum=0.937, weight_decay=5e-4)
    x = torch.rand(batch, 3, size, size, device=device)
    targets = torch.tensor([[i, i % NUM_CLASSES, 0.5, 0.5, 0.1, 0.1] for i in range(batch)], device=device)

    def step():
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            raw = model(x)
        loss, _ = loss_fn([p.float() for p in raw], targets)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()
        sync(device)

    step()
    started = time.perf_counter()
    for _ in progress(steps, f"training steps, batch {batch}", unit="step"):
        step()
    model.eval()
    return batch * steps / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--threads", type=int, nargs="+", default=[1, 2], help="CPU thread counts, for both backends"
    )
    parser.add_argument("--models", nargs="+", choices=list(MODELS), default=list(MODELS))
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--train-steps", type=int, default=3)
    parser.add_argument("--train-batch", type=int, default=8)
    parser.add_argument("--quick", action="store_true", help="320 only, fewer repeats (a smoke check)")
    args = parser.parse_args()
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    cpu = device.type == "cpu"
    sizes = (320,) if args.quick else (320, 640)
    repeats = 2 if args.quick else args.repeats
    modes = [False, True] if not cpu else [False]
    thread_counts = args.threads if cpu else args.threads[:1]
    peaks = {}
    for threads in thread_counts:
        torch.set_num_threads(threads)
        peaks[threads] = peak_flops(device, repeats=max(repeats, 3))
    load_before = os.getloadavg()

    records, rows = [], []
    peer_ms: dict[tuple, float] = {}  # yolov5s with torch, per (size, threads, amp)
    with tempfile.TemporaryDirectory() as onnx_dir:
        for mode_amp, name in itertools.product(modes, args.models):
            torch.manual_seed(0)
            model = YOLOv5(num_classes=NUM_CLASSES, **MODELS[name]).eval()
            flops = {size: forward_flops(model, size) for size in sizes}
            model.to(device)
            train_rate = None
            if 320 in sizes:  # before the timings: training leaves the model in eval mode, weights changed
                torch.set_num_threads(thread_counts[0])
                train_rate = training_rate(model, 320, args.train_batch, device, args.train_steps, mode_amp)
            for size, threads in itertools.product(sizes, thread_counts):
                torch.set_num_threads(threads)
                calls = {"torch": torch_call(model, size, device, mode_amp)}
                if cpu:
                    calls["onnxruntime"] = onnxruntime_call(model, size, threads, onnx_dir)
                medians = {backend: summarize(samples) for backend, samples in
                           interleaved_samples(calls, repeats=repeats)[0].items()}  # fmt: skip
                peer_ms.setdefault((size, threads, mode_amp), medians["torch"]["median"])
                bound_ms = flops[size] / peaks[threads] * 1e3
                for backend, stats in medians.items():
                    record = {
                        "model": name,
                        "parameters": count_parameters(model),
                        "image_size": size,
                        "backend": backend,
                        "threads": threads,
                        "amp": mode_amp,
                        "gflops": flops[size] / 1e9,
                        "inference_ms": stats,
                        "ratio_to_torch": stats["median"] / medians["torch"]["median"],
                        "ratio_to_yolov5s_torch": stats["median"] / peer_ms[(size, threads, mode_amp)],
                        "flop_bound_ms": bound_ms,
                        "ratio_to_flop_bound": stats["median"] / bound_ms,
                    }
                    if (size, threads, backend) == (320, thread_counts[0], "torch") and train_rate:
                        record["train_images_per_s"] = train_rate
                    records.append(record)
                    rows.append(
                        [name, size, backend, threads, "bf16" if mode_amp else "fp32", record["gflops"],
                         stats["median"], stats["p25"], stats["p75"], record["ratio_to_torch"],
                         record["ratio_to_yolov5s_torch"], bound_ms, record["ratio_to_flop_bound"],
                         record.get("train_images_per_s", "")]
                    )  # fmt: skip
                    print(rows[-1], flush=True)
    load_after = os.getloadavg()
    header = ["model", "size", "backend", "threads", "precision", "GFLOPs", "ms median", "p25", "p75",
              "x torch", "x yolov5s torch", "FLOP-bound ms", "x bound", "train img/s (320)"]  # fmt: skip
    device_name = torch.cuda.get_device_name(0) if not cpu else f"CPU, {os.cpu_count()} cores"
    peak_text = ", ".join(f"{peaks[t] / 1e9:.1f} GFLOP/s on {t} thread(s)" for t in thread_counts)
    table = (
        f"# Detector speed ({device_name})\n\n"
        f"Batch 1 inference (decode included, NMS excluded), {repeats} timed calls per row after 3 warm-up "
        f"calls; torch and ONNX Runtime alternate call by call. `x torch`: median / torch's median at the "
        f"same size and threads. Matrix-product peak {peak_text}.\n"
        f"1-minute load average {load_before[0]:.1f} before, {load_after[0]:.1f} after the run, on a "
        f"machine shared with other jobs: compare ratios within the run, not with other runs.\n"
        f"Training (torch, {thread_counts[0]} thread(s)): batch {args.train_batch} at 320 px, forward + "
        f"loss + backward + SGD step.\n\n" + markdown_table(header, rows)
    )
    write_report(
        "detector",
        {
            "device": device_name,
            "threads": thread_counts,
            "repeats": repeats,
            "load_average_1_5_15min": {"before": list(load_before), "after": list(load_after)},
            "peak_gflops": {str(t): peaks[t] / 1e9 for t in thread_counts},
            "results": records,
        },
        table,
    )
    print(table)


if __name__ == "__main__":
    main()
