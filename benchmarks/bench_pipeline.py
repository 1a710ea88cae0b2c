"""Time the whole pipeline per 640x480 frame, stage by stage: enhancement, detector (+NMS), re-ID, motion
fusion, dynamic filter, tracker; and re-tracking from the detection cache, which is what a sweep pays.

Contenders run on the same frames (held in memory: decoding is not the pipeline's cost) in interleaved
rounds; the peer is the paper's configuration: torch at the detector's 640 px input, stages one after
another. The others: torch at 320 px; ONNX Runtime at 320 px (`backend: auto` on a CPU): in turn, with the
motion stage overlapped in a thread, and with the re-ID of each frame also overlapped with the detector
of the next (the default), there also with the fusion's two detectors on two threads
(`motion.parallel=true`); the defaults on DWT/HSV-enhanced input. The networks are the shipped fold-3
models (`weights/`) unless told otherwise; with `--detector-weights none` the detector is randomly
initialised and, so that the re-ID and the tracker see a realistic load, the boxes passed on are the
sequence's ground truth.

    python benchmarks/bench_pipeline.py [--frames 60] [--rounds 3] [--threads 1] [--ort-threads 1]
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
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.device import resolve_device
from spacetrack.engine.checkpoint import save_checkpoint
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
    parser.add_argument("--frames", type=int, default=60)
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

    def stream(size: int, enhance: str, backend: str, *, overlap: bool = False, overlap_reid: bool = False,
               parallel_fusion: bool = False) -> DetectionStream:  # fmt: skip
        network = YoloDetector(weights=det_weights, image_size=size, device=str(device), backend=backend,
                               threads=args.ort_threads)  # fmt: skip
        detector = network if args.detector_weights else TimedNetworkTruthBoxes(network, truth)
        enhancer = instantiate(compose_config("track", [f"enhance={enhance}", "logger=none"]).enhance)
        return DetectionStream(
            enhancer=enhancer,
            detector=detector,
            encoder=encoders[backend],
            motion=instantiate(cfg.motion, parallel=parallel_fusion),
            dynamic_filter=build_dynamic_filter(cfg),
            overlap_motion=overlap,
            overlap_reid=overlap_reid,
            reid_min_score=cfg.reid.min_score,
        )

    ort = "torch" if device.type == "cuda" else "onnxruntime"  # what backend=auto runs
    both = {"overlap": True, "overlap_reid": True}
    contenders = {
        "torch 640, in turn (peer)": stream(640, "none", "torch"),
        "torch 320, in turn": stream(320, "none", "torch"),
        f"{ort} 320, in turn": stream(320, "none", ort),
        f"{ort} 320, motion overlapped": stream(320, "none", ort, overlap=True),
        f"{ort} 320, motion and re-ID overlapped (default)": stream(320, "none", ort, **both),
        f"{ort} 320, overlapped, fusion on two threads": stream(
            320, "none", ort, **both, parallel_fusion=True
        ),
        f"{ort} 320 + DWT/HSV, overlapped": stream(320, "dwt_hsv", ort, **both),
    }
    for s in contenders.values():  # warm-up: first calls allocate and pick kernels
        one_pass(s, frames[:3], args.sequence, cfg.tracker)
    samples: dict[str, list[float]] = {name: [] for name in contenders}
    stages: dict[str, list[dict]] = {name: [] for name in contenders}
    cache_samples: list[float] = []
    for _ in progress(args.rounds, "pipeline contenders", unit="round"):
        for name, s in contenders.items():
            seconds, by_stage = one_pass(s, frames, args.sequence, cfg.tracker)
            samples[name].append(seconds)
            stages[name].append(by_stage)
        recorded = list(
            contenders["torch 320, in turn"].run(
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
    peer = statistics.median(samples["torch 640, in turn (peer)"])
    record = {"device": device.type, "load_average_1_5_15min": list(os.getloadavg()), "frames": len(frames), "size": [width, height], "rounds": args.rounds, "threads": args.threads, "ort_threads": args.ort_threads,
              "detector_weights": "trained" if args.detector_weights else "random init, ground-truth boxes passed on",
              "contenders": {}}  # fmt: skip
    table = []
    for name in contenders:
        med = statistics.median(samples[name])
        by_stage = {k: statistics.median(s[k] for s in stages[name]) for k in stages[name][0]}
        record["contenders"][name] = {"ms_per_frame": 1e3 * med, "fps": 1 / med, "ratio_to_peer": med / peer,
                                      "stages_ms": by_stage, "samples_ms": [1e3 * s for s in samples[name]]}  # fmt: skip
        table.append([name, f"{1e3 * med:.1f}", f"{1 / med:.1f}", f"{med / peer:.2f}"]
                     + [f"{by_stage.get(k + '_ms', 0):.1f}" for k in ("enhance", "detector", "reid", "motion", "dynamic", "tracker")])  # fmt: skip
    cached = statistics.median(cache_samples)
    record["contenders"]["tracking from the cache"] = {
        "ms_per_frame": 1e3 * cached,
        "fps": 1 / cached,
        "ratio_to_peer": cached / peer,
    }
    table.append(["tracking from the cache", f"{1e3 * cached:.2f}", f"{1 / cached:.0f}", f"{cached / peer:.3f}"] + ["-"] * 5 + [f"{1e3 * cached:.2f}"])  # fmt: skip
    header = [
        "contender",
        "ms/frame",
        "fps",
        "ratio to peer",
        "enhance",
        "detector",
        "re-ID",
        "motion",
        "dynamic",
        "tracker",
    ]
    md = (
        f"# Whole pipeline per {width}x{height} frame ({device.type.upper()}, {args.threads} torch threads, "
        f"{args.ort_threads} onnxruntime threads)\n\n"
        f"{len(frames)} frames of {args.sequence}, {args.rounds} interleaved rounds, medians; stage columns in ms"
        f" per frame. Detector: {record['detector_weights']}. Load average during the run:"
        f" {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (a machine shared with other jobs).\n\n"
        + markdown_table(header, table)
    )
    write_report("pipeline", record, md)
    print(md)


if __name__ == "__main__":
    main()
