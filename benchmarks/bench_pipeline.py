"""Time the whole pipeline per 640x480 frame, stage by stage, against the reference YOLOv5s detector alone.

Stages: enhancement, detector (+NMS), re-ID, motion fusion, dynamic filter, tracker; and re-tracking from
the detection cache, which is what a sweep pays. Contenders run on the same frames (held in memory:
decoding is not the pipeline's cost) in interleaved rounds. The peer is the reference YOLOv5s detector
alone (the registry's `yolov5` package, `peer_yolov5.py`: fused, eval, random init) on each frame
letterboxed to 640x640, with 1 and with 2 torch threads; the ratio of a pipeline is to the faster of the
two, from the same rounds. Ours are the whole pipeline with enhancement off and the detector at native
resolution (640x480), motion and re-ID overlapped with it (the defaults), for each detector backend:
onnxruntime (float32, what `backend: auto` runs on a CPU), onnxruntime_int8 and torch; and, for
comparison, onnxruntime at a 320-px letterbox (what native resolution costs). Without the `yolov5` package the peer
rows are left out (the reason is printed) and the ratios are to our torch pipeline instead. The networks
are the shipped fold-3 models (`weights/`) unless told otherwise; with `--detector-weights none` the
detector is randomly initialised and, so that the re-ID and the tracker see a realistic load, the boxes
passed on are the sequence's ground truth.

    python benchmarks/bench_pipeline.py [--frames 30] [--rounds 3] [--threads 1] [--ort-threads 1]
    python benchmarks/bench_pipeline.py --detector-weights best.pt --reid-weights reid.pt   # other models
"""

from __future__ import annotations

import argparse
import itertools
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from common import markdown_table, progress, write_report
from peer_yolov5 import reference_yolov5s
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.device import resolve_device
from spacetrack.engine.checkpoint import save_checkpoint
from spacetrack.engine.inference import network_input
from spacetrack.models.yolo import YOLOv5
from spacetrack.pipeline import DetectionStream, GroundTruthDetector, StageTimer, YoloDetector
from spacetrack.pipeline.build import build_dynamic_filter
from spacetrack.pipeline.cache import CachedSequence
from spacetrack.pipeline.runner import cached_frames
from spacetrack.pipeline.sources import FrameSource, sequence_source
from spacetrack.reid import Encoder
from spacetrack.reid.weights import save_weights


class TimedNetworkTruthBoxes:
    """Runs the detector network on every frame (timed by the caller) and passes on the true boxes."""

    def __init__(self, network: YoloDetector, truth: GroundTruthDetector) -> None:
        self.network, self.truth = network, truth

    def begin(self, source: FrameSource) -> None:
        self.truth.begin(source)

    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        self.network(rgb, frame)
        return self.truth(rgb, frame)


def _kwargs(node) -> dict:
    return {k: v for k, v in OmegaConf.to_container(node, resolve=True).items() if k != "_target_"}


def random_weights(folder: Path) -> tuple[Path, Path]:
    """A random-init YOLOv5s (3 classes) checkpoint and Table 1 re-ID weights: real shapes, real cost."""
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3)
    detector = folder / "yolov5s.pt"
    save_checkpoint(detector, {"arch": model.arch, "ema": model.state_dict()})
    cfg = compose_config("train_reid", ["logger=none"])
    reid = folder / "reid.pt"
    save_weights(
        reid,
        instantiate(cfg.model.net),
        net_kwargs=_kwargs(cfg.model.net),
        crop_kwargs=_kwargs(cfg.model.crop),
    )
    return detector, reid


def one_pass(stream: DetectionStream, frames: list[np.ndarray], name: str, tracker_cfg) -> tuple[float, dict]:
    """Seconds per frame of the whole pipeline on `frames`, and ms per frame by stage."""
    stream.timer = StageTimer()
    tracker = instantiate(tracker_cfg)
    source = FrameSource(name, name, 10.0, len(frames), iter(frames))
    start = time.perf_counter()
    for item in stream.run(source):
        with stream.timer("tracker"):
            tracker.step(
                item.rows[item.dynamic, 2:6], item.rows[item.dynamic, 6], item.rows[item.dynamic, 10:]
            )
    return (time.perf_counter() - start) / len(frames), stream.timer.ms_per_frame(len(frames))


SHIPPED_DETECTOR = REPO_ROOT / "weights" / "detector_yolov5s_fold3.pt"
SHIPPED_REID = REPO_ROOT / "weights" / "reid_fold3.pt"


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--dataset", default="data/space_default")
    parser.add_argument("--sequence", default="seq_000_nominal")
    parser.add_argument("--frames", type=int, default=30)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--threads", type=int, default=1, help="torch threads (1 is fastest on a crowded machine)"
    )
    parser.add_argument(
        "--ort-threads", type=int, default=1, help="onnxruntime intra-op threads (0: its default)"
    )
    parser.add_argument("--device", default="auto", help="auto (CUDA when present), cpu or cuda")
    parser.add_argument(
        "--detector-weights", help="a trained best.pt (default: the shipped fold-3 one; none)"
    )
    parser.add_argument("--reid-weights", help="a trained reid.pt (default: the shipped fold-3 one; none)")
    args = parser.parse_args()
    # default: the shipped weights (a clone has them); `none`: random init, ground-truth boxes passed on
    for key, shipped in (("detector_weights", SHIPPED_DETECTOR), ("reid_weights", SHIPPED_REID)):
        value = getattr(args, key)
        if value is None and shipped.is_file():
            setattr(args, key, str(shipped))
        elif value == "none":
            setattr(args, key, None)
    torch.set_num_threads(args.threads)
    cfg = compose_config("track", ["logger=none", "tracker=deepsort_paper"])
    source = sequence_source(args.dataset, args.sequence)
    frames = list(itertools.islice(source, args.frames))
    height, width = frames[0].shape[:2]
    scratch = tempfile.TemporaryDirectory()  # the random weights; removed when the run ends
    det_weights, reid_weights = random_weights(Path(scratch.name))
    det_weights = Path(args.detector_weights or det_weights)
    device = resolve_device(args.device)
    reid_path = args.reid_weights or reid_weights
    encoders = {
        backend: Encoder.from_weights(reid_path, device=device, backend=backend, threads=args.ort_threads)
        for backend in ("torch", "onnxruntime")
    }
    truth = GroundTruthDetector(root=args.dataset)

    def stream(size: int | None, enhance: str, backend: str, *, overlap: bool = False, overlap_reid: bool = False,
               parallel_fusion: bool = False) -> DetectionStream:  # fmt: skip
        network = YoloDetector(weights=det_weights, image_size=size, device=str(device), backend=backend,
                               threads=args.ort_threads)  # fmt: skip
        detector = network if args.detector_weights else TimedNetworkTruthBoxes(network, truth)
        enhancer = instantiate(compose_config("track", [f"enhance={enhance}", "logger=none"]).enhance)
        return DetectionStream(
            enhancer=enhancer,
            detector=detector,
            encoder=encoders["torch" if backend == "torch" else "onnxruntime"],
            motion=instantiate(cfg.motion, parallel=parallel_fusion),
            dynamic_filter=build_dynamic_filter(cfg),
            overlap_motion=overlap,
            overlap_reid=overlap_reid,
            reid_min_score=cfg.reid_min_score,
        )

    cpu = device.type == "cpu"
    ort = "onnxruntime" if cpu else "torch"  # what backend=auto runs
    both = {"overlap": True, "overlap_reid": True}
    contenders = {f"ours, {ort} native (auto, the default)": stream(None, "none", ort, **both)}
    if cpu:
        contenders["ours, onnxruntime_int8 native"] = stream(None, "none", "onnxruntime_int8", **both)
    contenders["ours, torch native"] = stream(None, "none", "torch", **both)
    contenders[f"ours, {ort} 320 letterbox"] = stream(320, "none", ort, **both)
    peer, peer_text = reference_yolov5s(3)
    print(peer_text, flush=True)
    peers = {}
    if peer is not None:
        peer.to(device)
        x = torch.from_numpy(network_input(frames[0], 640)[0]).permute(2, 0, 1)[None].float().div(255)
        peer_input = x.to(device)
        for threads in sorted({1, 2} if cpu else {args.threads}):
            peers[f"reference YOLOv5s alone, 640x640, {threads} thread(s)"] = (peer, peer_input, threads)

    def peer_pass(net, x, threads: int, count: int) -> float:
        """Seconds per frame of the reference detector alone (its input prepared once)."""
        torch.set_num_threads(threads)
        start = time.perf_counter()
        with torch.inference_mode():
            for _ in range(count):
                net(x)
                if device.type == "cuda":
                    torch.cuda.synchronize()
        torch.set_num_threads(args.threads)
        return (time.perf_counter() - start) / count

    for s in contenders.values():  # warm-up: first calls allocate, pick kernels, quantise once
        one_pass(s, frames[:3], args.sequence, cfg.tracker)
    for item in peers.values():
        peer_pass(*item, 3)
    samples: dict[str, list[float]] = {name: [] for name in [*peers, *contenders]}
    stages: dict[str, list[dict]] = {name: [] for name in contenders}
    cache_samples: list[float] = []
    for _ in progress(args.rounds, "pipeline contenders", unit="round"):
        for name, item in peers.items():
            samples[name].append(peer_pass(*item, len(frames)))
        for name, s in contenders.items():
            seconds, by_stage = one_pass(s, frames, args.sequence, cfg.tracker)
            samples[name].append(seconds)
            stages[name].append(by_stage)
        recorded = list(
            contenders[f"ours, {ort} 320 letterbox"].run(
                FrameSource(args.sequence, "cache run", 10.0, len(frames), iter(frames))
            )
        )
        from_cache = CachedSequence(
            rows=np.concatenate([r.rows for r in recorded]),
            classes=np.concatenate([r.classes for r in recorded]),
            num_frames=len(frames),
            blobs=[r.blobs for r in recorded],
        )
        tracker, dynamic_filter = instantiate(cfg.tracker), build_dynamic_filter(cfg)
        start = time.perf_counter()  # the dynamic flags come from the cached blobs, as in `make track`
        for item in cached_frames(from_cache, dynamic_filter, None):
            tracker.step(
                item.rows[item.dynamic, 2:6], item.rows[item.dynamic, 6], item.rows[item.dynamic, 10:]
            )
        cache_samples.append((time.perf_counter() - start) / len(frames))
    medians = {name: statistics.median(v) for name, v in samples.items()}
    # the reference at its faster thread count (our torch pipeline without the package)
    peer_name = min(peers, key=medians.get) if peers else "ours, torch native"
    peer_med = medians[peer_name]
    record = {"device": device.type, "load_average_1_5_15min": list(os.getloadavg()), "frames": len(frames), "size": [width, height], "rounds": args.rounds, "threads": args.threads, "ort_threads": args.ort_threads,
              "detector_weights": "trained" if args.detector_weights else "random init, ground-truth boxes passed on",
              "peer": peer_text, "ratio_reference": peer_name, "contenders": {}}  # fmt: skip
    table = []
    for name in samples:
        med = medians[name]
        entry = {"ms_per_frame": 1e3 * med, "fps": 1 / med, "ratio_to_peer": med / peer_med,
                 "samples_ms": [1e3 * v for v in samples[name]]}  # fmt: skip
        by_stage = {}
        if name in stages:
            by_stage = {k: statistics.median(s[k] for s in stages[name]) for k in stages[name][0]}
            entry["stages_ms"] = by_stage
        record["contenders"][name] = entry
        cells = [f"{by_stage.get(k + '_ms', 0):.1f}" if by_stage else "-"
                 for k in ("enhance", "detector", "reid", "motion", "dynamic", "tracker")]  # fmt: skip
        table.append([name, f"{1e3 * med:.1f}", f"{1 / med:.1f}", f"{med / peer_med:.2f}", *cells])
    cached = statistics.median(cache_samples)
    record["contenders"]["tracking from the cache"] = {
        "ms_per_frame": 1e3 * cached,
        "fps": 1 / cached,
        "ratio_to_peer": cached / peer_med,
    }
    table.append(["tracking from the cache", f"{1e3 * cached:.2f}", f"{1 / cached:.0f}", f"{cached / peer_med:.3f}"] + ["-"] * 5 + [f"{1e3 * cached:.2f}"])  # fmt: skip
    native = [n for n in contenders if "native" in n]
    best = min(native, key=medians.get)
    record["target"] = {
        "target": "the whole pipeline at native resolution <= 0.8x the reference detector alone at 640x640",
        "pipeline": best,
        "ratio": medians[best] / peer_med,
        "met": bool(peers) and medians[best] / peer_med <= 0.8,
    }
    header = ["contender", "ms/frame", "fps", "ratio to peer", "enhance", "detector", "re-ID", "motion",
              "dynamic", "tracker"]  # fmt: skip
    verdict = "met" if record["target"]["met"] else "not met"
    md = (
        f"# Whole pipeline per {width}x{height} frame against the reference detector alone "
        f"({device.type.upper()}, {args.threads} torch threads, {args.ort_threads} onnxruntime threads)\n\n"
        f"{len(frames)} frames of {args.sequence}, {args.rounds} interleaved rounds, medians; stage columns in ms"
        f" per frame (stages overlap, so they need not add up). Detector: {record['detector_weights']}."
        f" Peer: {peer_text}; ratios are to {peer_name}. Load average during the run:"
        f" {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (a machine shared with other jobs).\n\n"
        f"Target (issue 19): the whole pipeline at native resolution <= 0.8x the reference detector alone:"
        f" {best}, {medians[best] / peer_med:.2f}x, **{verdict}**.\n\n" + markdown_table(header, table)
    )
    write_report("pipeline", record, md)
    print(md)


if __name__ == "__main__":
    main()
