"""Detector speed: inference ms per image at 320 and 640 pixels, and training images per second.

Contenders: YOLOv5s (the peer), YOLOv5s + GAM and YOLOv5s + grouped GAM, timed in the same run. Each
inference time is also compared with its FLOP bound: the model's multiply-adds (counted by torch's
FLOP counter) divided by the rate this machine reaches on a large matrix product with the same
number of threads. On a GPU the same is measured in float32 and with AMP (bfloat16 autocast).

    python benchmarks/bench_detector.py [--threads 1] [--repeats 7] [--quick]
"""

from __future__ import annotations

import argparse
import time

import torch
from torch.utils.flop_counter import FlopCounterMode

from common import markdown_table, summarize, time_call, write_report
from spacetrack.engine.loss import YoloLoss
from spacetrack.engine.optim import build_optimizer
from spacetrack.models.yolo import YOLOv5, count_parameters

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


def time_inference(model, size, device, repeats, amp):
    x = torch.rand(1, 3, size, size, device=device)

    def step():
        with torch.no_grad(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            model.predict(x)
        sync(device)

    return time_call(step, repeats=repeats, warmup=2)


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
    for _ in range(steps):
        step()
    model.eval()
    return batch * steps / (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--threads", type=int, default=1, help="torch CPU threads (1: stable on a busy machine)"
    )
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--train-steps", type=int, default=3)
    parser.add_argument("--train-batch", type=int, default=8)
    parser.add_argument("--quick", action="store_true", help="320 only, fewer repeats (a smoke check)")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    sizes = (320,) if args.quick else (320, 640)
    repeats = 2 if args.quick else args.repeats
    modes = [False, True] if device.type == "cuda" else [False]
    peak = peak_flops(device, repeats=max(repeats, 3))

    records, rows = [], []
    for mode_amp in modes:
        peer_ms: dict[int, float] = {}
        for name, extra in MODELS.items():
            torch.manual_seed(0)
            model = YOLOv5(num_classes=NUM_CLASSES, **extra).eval()
            flops = {size: forward_flops(model, size) for size in sizes}
            model.to(device)
            for size in sizes:
                stats = summarize(time_inference(model, size, device, repeats, mode_amp))
                peer_ms.setdefault(size, stats["median"])
                bound_ms = flops[size] / peak * 1e3
                record = {
                    "model": name,
                    "parameters": count_parameters(model),
                    "image_size": size,
                    "amp": mode_amp,
                    "gflops": flops[size] / 1e9,
                    "inference_ms": stats,
                    "ratio_to_yolov5s": stats["median"] / peer_ms[size],
                    "flop_bound_ms": bound_ms,
                    "ratio_to_flop_bound": stats["median"] / bound_ms,
                }
                if size == 320:
                    record["train_images_per_s"] = training_rate(
                        model, size, args.train_batch, device, args.train_steps, mode_amp
                    )
                records.append(record)
                rows.append(
                    [name, size, "bf16" if mode_amp else "fp32", record["gflops"], stats["median"],
                     stats["p25"], stats["p75"], record["ratio_to_yolov5s"], bound_ms,
                     record["ratio_to_flop_bound"], record.get("train_images_per_s", "")]
                )  # fmt: skip
                print(rows[-1], flush=True)
    header = ["model", "size", "precision", "GFLOPs", "ms median", "p25", "p75", "x yolov5s",
              "FLOP-bound ms", "x bound", "train img/s (320)"]  # fmt: skip
    device_name = torch.cuda.get_device_name(0) if device.type == "cuda" else f"CPU, {args.threads} thread(s)"
    table = (
        f"# Detector speed ({device_name})\n\n"
        f"Batch 1 inference (decode included, NMS excluded); matrix-product peak {peak / 1e9:.1f} GFLOP/s.\n"
        f"Training: batch {args.train_batch} at 320 px, forward + loss + backward + SGD step.\n\n"
        + markdown_table(header, rows)
    )
    write_report(
        "detector",
        {"device": device_name, "threads": args.threads, "peak_gflops": peak / 1e9, "results": records},
        table,
    )
    print(table)


if __name__ == "__main__":
    main()
