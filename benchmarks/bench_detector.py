"""Detector speed against the reference YOLOv5s: ms per image at 320, 640 and native 640x480 pixels.

The peer is the registry's `yolov5` package (ultralytics v7.0 packaged, `peer_yolov5.py`): YOLOv5s built
from its yaml, Conv+BN fused, eval mode. Ours are the pipeline's backends (`detector.backend`) on the
shipped fold-3 weights (random init when they are missing):
- torch: the Conv+BN fused copy under inference_mode, channels-last (and "torch NCHW", the same copy in
  the default layout, which shows what channels-last brings);
- torch_bf16, only where the CPU computes bfloat16 natively (on a GPU: AMP);
- onnxruntime: float32, what `backend: auto` runs on a CPU;
- onnxruntime_int8: the graph quantised to INT8, calibrated on the training folds' frames.
At each thread count the contenders at one size are timed round-robin, one call each per round, so that
load from other processes hits all alike; the 640 rounds also hold ours at native 640x480, so that their
ratio to the peer's 640x640 comes from the same rounds. Every time is batch 1, float input in, decoded
boxes out (NMS excluded). Each row also gives its FLOP bound (multiply-adds over this machine's matrix
product rate at that thread count) and, at 320 px, the training rate of YOLOv5s (random init).

    python benchmarks/bench_detector.py [--threads 1 2] [--repeats 7] [--quick] [--models yolov5s_gam]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

import numpy as np
import torch
from torch.utils.flop_counter import FlopCounterMode

from common import interleaved_samples, markdown_table, progress, summarize, time_call, write_report
from peer_yolov5 import reference_yolov5s
from spacetrack.config import REPO_ROOT
from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.engine.loss import YoloLoss
from spacetrack.engine.optim import build_optimizer
from spacetrack.engine.precision import native_bfloat16
from spacetrack.models.yolo import YOLOv5, fuse_for_inference
from spacetrack.pipeline.detector import YoloDetector

SHIPPED = REPO_ROOT / "weights" / "detector_yolov5s_fold3.pt"
GAM_MODELS = {
    "yolov5s_gam": {"gam_position": "after_sppf"},
    "yolov5s_gam_light": {"gam_position": "after_sppf", "gam_groups": 4},
}
NUM_CLASSES = 3
PEER = "reference yolov5s (peer)"
NATIVE = (480, 640)
GPU_BATCH = 32


def forward_flops(model: torch.nn.Module, shape: tuple[int, int]) -> int:
    """Floating-point operations (2 per multiply-add) of one forward pass on an image of `shape`."""
    counter = FlopCounterMode(display=False)
    with counter, torch.no_grad():
        model(torch.zeros(1, 3, *shape))
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


def torch_call(network, shape, device, *, channels_last=False, amp=False, threads=None, batch=1):
    """One forward with box decoding on a random image batch, as a timed callable; `threads` sets torch's
    thread count first (the contenders of one round share the process)."""
    x = torch.rand(batch, 3, *shape, device=device)
    if channels_last:
        x = x.contiguous(memory_format=torch.channels_last)
    forward = network.predict if hasattr(network, "predict") else network

    def step():
        if threads:
            torch.set_num_threads(threads)
        with torch.inference_mode(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            forward(x)
        sync(device)

    return step


def session_call(session, shape):
    x = np.random.default_rng(0).random((1, 3, *shape), dtype=np.float32)
    return lambda: session(x)


def training_rate(model, size, batch, device, steps) -> float:
    """Images per second of forward, loss, backward and SGD step on random images with one target each."""
    model.train()
    loss_fn = YoloLoss(
        anchors=model.detect.anchors, strides=model.stride, num_classes=NUM_CLASSES, image_size=size
    )
    optimizer = build_optimizer(model, lr0=0.01, momentum=0.937, weight_decay=5e-4)
    x = torch.rand(batch, 3, size, size, device=device)
    targets = torch.tensor([[i, i % NUM_CLASSES, 0.5, 0.5, 0.1, 0.1] for i in range(batch)], device=device)

    def step():
        loss, _ = loss_fn([p.float() for p in model(x)], targets)
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


class Ours:
    """Our detector's backends on one checkpoint, built once; sessions per input shape are cached."""

    def __init__(self, weights, device, onnx_dir, threads):
        self.device = device
        kwargs = {"weights": weights, "device": device.type, "onnx_dir": onnx_dir}
        self.torch = YoloDetector(backend="torch", **kwargs)
        self.nchw = fuse_for_inference(self.torch.model).to(device)
        self.ort = {t: YoloDetector(backend="onnxruntime", threads=t, **kwargs) for t in threads}
        self.int8 = {t: YoloDetector(backend="onnxruntime_int8", threads=t, **kwargs) for t in threads}
        self.int8_missing = None

    def calls(self, shape, threads, cpu) -> dict:
        h, w = shape
        tag = f"{w}x{h}"
        out = {
            f"ours torch {tag}": torch_call(self.torch.network, shape, self.device, threads=threads,
                                            channels_last=cpu),
        }  # fmt: skip
        if cpu:
            out[f"ours torch NCHW {tag}"] = torch_call(self.nchw, shape, self.device, threads=threads)
            if native_bfloat16():
                out[f"ours torch_bf16 {tag}"] = torch_call(
                    self.torch.network, shape, self.device, threads=threads, channels_last=True, amp=True
                )
            out[f"ours onnxruntime {tag}"] = session_call(self.ort[threads].session(h, w), shape)
            if self.int8_missing is None:
                try:
                    out[f"ours onnxruntime_int8 {tag}"] = session_call(
                        self.int8[threads].session(h, w), shape
                    )
                except (FileNotFoundError, ValueError) as err:  # no calibration data here
                    self.int8_missing = f"INT8 left out: {err}"
                    print(self.int8_missing, flush=True)
        else:  # on a GPU: AMP at batch 1, and the batch throughput with AMP
            out[f"ours torch AMP {tag}"] = torch_call(self.torch.network, shape, self.device, amp=True)
            out[f"ours torch AMP batch {GPU_BATCH} {tag}"] = torch_call(
                self.torch.network, shape, self.device, amp=True, batch=GPU_BATCH
            )
        return out


def gam_calls(shape, threads, device, onnx_dir, cache) -> dict:
    """The GAM variants (random init): torch fused and ONNX Runtime float32."""
    out = {}
    for name, extra in GAM_MODELS.items():
        if name not in cache:
            torch.manual_seed(0)
            model = YOLOv5(num_classes=NUM_CLASSES, **extra)
            path = os.path.join(onnx_dir, f"{name}.pt")
            save_checkpoint(path, {"arch": model.arch, "ema": model.state_dict()})
            cache[name] = path
        kwargs = {"weights": cache[name], "device": device.type, "onnx_dir": onnx_dir}
        det = YoloDetector(backend="torch", **kwargs)
        out[f"{name} torch {shape[1]}x{shape[0]}"] = torch_call(det.network, shape, device, threads=threads,
                                                               channels_last=device.type == "cpu")  # fmt: skip
        if device.type == "cpu":
            ort = YoloDetector(backend="onnxruntime", threads=threads, **kwargs)
            out[f"{name} onnxruntime {shape[1]}x{shape[0]}"] = session_call(ort.session(*shape), shape)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="CPU thread counts")
    parser.add_argument("--models", nargs="*", choices=list(GAM_MODELS), default=[],
                        help="also time these GAM variants (random init, torch and ONNX Runtime)")  # fmt: skip
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--train-steps", type=int, default=3, help="0: leave out the training rate")
    parser.add_argument("--train-batch", type=int, default=8)
    parser.add_argument("--weights", default=None, help="our checkpoint (default: the shipped fold-3 one)")
    parser.add_argument("--quick", action="store_true", help="320 only, 2 repeats (a smoke check)")
    args = parser.parse_args()
    device = torch.device("cuda" if torch.cuda.is_available() else "cpu")
    cpu = device.type == "cpu"
    sizes = (320,) if args.quick else (320, 640)
    repeats = 2 if args.quick else args.repeats
    thread_counts = args.threads if cpu else args.threads[:1]
    peer, peer_text = reference_yolov5s(NUM_CLASSES)
    print(peer_text, flush=True)
    if peer is not None:
        peer.to(device)
    peaks = {}
    for threads in thread_counts:
        torch.set_num_threads(threads)
        peaks[threads] = peak_flops(device, repeats=max(repeats, 3))
    load_before = os.getloadavg()
    scratch = tempfile.TemporaryDirectory()
    weights = args.weights or (str(SHIPPED) if SHIPPED.is_file() else None)
    if weights is None:
        torch.manual_seed(0)
        model = YOLOv5(num_classes=NUM_CLASSES)
        weights = os.path.join(scratch.name, "yolov5s.pt")
        save_checkpoint(weights, {"arch": model.arch, "ema": model.state_dict()})
    weights_text = "shipped fold-3 weights" if weights == str(SHIPPED) else str(weights)
    onnx_dir = None if weights == str(SHIPPED) else scratch.name  # the shipped exports stay cached
    ours = Ours(weights, device, onnx_dir, thread_counts)
    flop_model = ours.torch.model
    flops: dict[tuple[int, int], int] = {}
    train_rate = None
    if args.train_steps > 0:
        torch.set_num_threads(thread_counts[0])
        torch.manual_seed(0)
        trained = YOLOv5(num_classes=NUM_CLASSES).to(device)
        train_rate = training_rate(trained, 320, args.train_batch, device, args.train_steps)
    gam_cache: dict[str, str] = {}
    records, rows = [], []
    for threads in thread_counts:
        for size in sizes:
            torch.set_num_threads(threads)
            shapes = [(size, size)] + ([NATIVE] if size == 640 else [])
            calls = {}
            if peer is not None:
                calls[PEER] = torch_call(peer, (size, size), device, threads=threads)
            for shape in shapes:
                calls.update(ours.calls(shape, threads, cpu))
                if args.models:
                    calls.update({k: v for k, v in gam_calls(shape, threads, device, scratch.name, gam_cache).items()
                                  if any(k.startswith(m + " ") for m in args.models)})  # fmt: skip
            wall, _ = interleaved_samples(calls, repeats=repeats)
            stats = {name: summarize(samples) for name, samples in wall.items()}
            peer_ms = stats[PEER]["median"] if PEER in stats else None
            for name, s in stats.items():
                shape = NATIVE if name.endswith(f"{NATIVE[1]}x{NATIVE[0]}") else (size, size)
                if shape not in flops:
                    flops[shape] = forward_flops(flop_model, shape)
                bound_ms = flops[shape] / peaks[threads] * 1e3
                batch = GPU_BATCH if f"batch {GPU_BATCH} " in name else 1
                record = {
                    "contender": name,
                    "batch": batch,
                    "images_per_s": batch * 1e3 / s["median"],
                    "input": f"{shape[1]}x{shape[0]}",
                    "threads": threads,
                    "gflops": flops[shape] / 1e9,
                    "inference_ms": s,
                    "ratio_to_peer": s["median"] / peer_ms if peer_ms else None,
                    "flop_bound_ms": bound_ms,
                    "ratio_to_flop_bound": s["median"] / bound_ms,
                }
                records.append(record)
                ratio = f"{record['ratio_to_peer']:.2f}" if peer_ms else "-"
                rows.append([name, record["input"], threads, f"{s['median']:.1f}", f"{s['p25']:.1f}",
                             f"{s['p75']:.1f}", ratio, f"{bound_ms:.1f}", f"{record['ratio_to_flop_bound']:.2f}"])  # fmt: skip
                print(rows[-1], flush=True)
    load_after = os.getloadavg()
    targets = target_checks(records, peer is not None)
    header = ["contender", "input", "threads", "ms median", "p25", "p75", "x peer (same rounds)",
              "FLOP-bound ms", "x bound"]  # fmt: skip
    device_name = torch.cuda.get_device_name(0) if not cpu else f"CPU, {os.cpu_count()} cores"
    peak_text = ", ".join(f"{peaks[t] / 1e9:.1f} GFLOP/s on {t} thread(s)" for t in thread_counts)
    target_rows = [[t["target"], f"{t['measured']:.2f}" if t["measured"] is not None else "-", t["bound"],
                    "met" if t["met"] else "not met"] for t in targets]  # fmt: skip
    table = (
        f"# Detector speed against the reference YOLOv5s ({device_name})\n\n"
        f"Peer: {peer_text}. Ours: {weights_text}. Batch 1, float input, decoded boxes out (NMS excluded); "
        f"{repeats} timed rounds after 3 warm-up calls, the contenders of one size and thread count "
        f"alternating call by call; `x peer`: median / the peer's median in the same rounds (ours at "
        f"640x480 against the peer at 640x640). Matrix-product peak {peak_text}.\n"
        f"1-minute load average {load_before[0]:.1f} before, {load_after[0]:.1f} after the run, on a "
        f"machine shared with other jobs: compare ratios within the run, not with other runs.\n"
        + (f"bfloat16: {'native' if native_bfloat16() else 'not native on this CPU (no AVX512-BF16/AMX): left out'}.\n" if cpu else "")
        + (f"Training (YOLOv5s, random init, torch, {thread_counts[0]} thread(s)): {train_rate:.2f} img/s, "
           f"batch {args.train_batch} at 320 px, forward + loss + backward + SGD step.\n" if train_rate else "")
        + "\n## Targets\n\n" + markdown_table(["target", "measured", "bound", "verdict"], target_rows)
        + "\n## All contenders\n\n" + markdown_table(header, rows)
    )  # fmt: skip
    write_report(
        "detector",
        {
            "device": device_name,
            "peer": peer_text,
            "ours": weights_text,
            "threads": thread_counts,
            "repeats": repeats,
            "load_average_1_5_15min": {"before": list(load_before), "after": list(load_after)},
            "peak_gflops": {str(t): peaks[t] / 1e9 for t in thread_counts},
            "bfloat16_native": native_bfloat16() if cpu else None,
            "train_images_per_s_320": train_rate,
            "targets": targets,
            "results": records,
        },
        table,
    )
    print(table)


def target_checks(records: list[dict], have_peer: bool) -> list[dict]:
    """Issue 19's detector targets, from the ratios of this run."""
    if not have_peer:
        return []
    by = {(r["contender"], r["threads"]): r for r in records}
    out = []
    plain = ("ours torch 320x320", "ours torch 640x640")  # the fused channels-last torch backend
    for (name, threads), r in sorted(by.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        if name in plain:
            out.append({"target": f"our torch at {r['input']}, {threads} thread(s) <= 1.0x peer",
                        "measured": r["ratio_to_peer"], "bound": "<= 1.0", "met": r["ratio_to_peer"] <= 1.0})  # fmt: skip
    for threads in sorted({t for _, t in by}):
        native = [
            r for (n, t), r in by.items() if t == threads and r["input"] == "640x480" and n.startswith("ours")
        ]
        if native:
            best = min(native, key=lambda r: r["ratio_to_peer"])
            out.append({"target": f"fastest backend at native 640x480 ({best['contender']}), {threads} thread(s) "
                                  "<= 0.4x peer at 640x640",
                        "measured": best["ratio_to_peer"], "bound": "<= 0.4", "met": best["ratio_to_peer"] <= 0.4})  # fmt: skip
    return out


if __name__ == "__main__":
    main()
