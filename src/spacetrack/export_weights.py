"""Shrink trained weights for shipping: the detector's EMA weights and the re-ID network in fp16, or
both networks as float32 ONNX graphs for ONNX Runtime elsewhere.

    python -m spacetrack.export_weights --detector outputs/train/<run>/weights/best.pt \\
        --reid outputs/train_reid/space_default/fold3/reid.pt --out weights/
    python -m spacetrack.export_weights --onnx --image-size 640x480 --detector weights/detector_yolov5s_fold3.pt \\
        --reid weights/reid_fold3.pt --out outputs/

The detector file keeps what `spacetrack.engine.checkpoint.load_detector` needs (`arch`, `ema`) plus the
training settings and history; optimiser state and the raw weights are dropped. Both loaders cast the
fp16 tensors back to the model's float32 on load.

The ONNX graphs are the ones the pipeline's `backend=onnxruntime` runs: the detector takes one
(1, 3, H, W) float32 RGB image in [0, 1] (--image-size WxH: a native frame padded to multiples of 32;
or S: letterboxed to S x S) and gives (1, N, 5 + classes)
rows `cx, cy, w, h` in pixels, objectness and class scores, before NMS; the re-ID network takes
(N, 3, 128, 64) crops in [0, 1] and gives (N, 128) unit features.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from spacetrack import cli
from spacetrack.engine.checkpoint import load_checkpoint, load_detector
from spacetrack.io import atomic_path, load_torch_file
from spacetrack.onnx_backend import export_onnx
from spacetrack.pipeline.detector import onnx_graph
from spacetrack.reid.encoder import onnx_input_shape
from spacetrack.reid.weights import load_weights


def _half(state: dict) -> dict:
    return {k: v.half() if torch.is_tensor(v) and v.is_floating_point() else v for k, v in state.items()}


def export_detector(src: str | Path, dst: str | Path) -> Path:
    state = load_checkpoint(src)
    slim = {k: state[k] for k in ("arch", "settings", "history", "epoch", "best_fitness") if k in state}
    slim["ema"] = _half(state["ema"])
    with atomic_path(dst) as tmp:
        torch.save(slim, tmp)
    return Path(dst)


def export_reid(src: str | Path, dst: str | Path) -> Path:
    load_weights(src)  # refuse a file that is not re-ID weights before writing anything
    state = load_torch_file(src, "weights file")
    state["model"] = _half(state["model"])
    with atomic_path(dst) as tmp:
        torch.save(state, tmp)
    return Path(dst)


def input_size(text: str) -> tuple[int, int]:
    """(height, width) of `--image-size`: `WxH` or a square side `S`, each a multiple of 32."""
    try:
        width, height = (int(v) for v in text.lower().split("x")) if "x" in text.lower() else (int(text),) * 2
    except ValueError:
        raise argparse.ArgumentTypeError(f"--image-size must be WxH or S in pixels, got {text!r}") from None
    if width <= 0 or height <= 0 or width % 32 or height % 32:
        raise argparse.ArgumentTypeError(f"--image-size sides must be positive multiples of 32, got {text!r}")
    return height, width


def export_detector_onnx(
    src: str | Path, dst: str | Path, *, image_size: tuple[int, int] = (480, 640)
) -> Path:
    """The detector's ONNX graph for (height, width) inputs."""
    return export_onnx(*onnx_graph(load_detector(src), *image_size), dst)


def export_reid_onnx(src: str | Path, dst: str | Path) -> Path:
    net, _ = load_weights(src)
    return export_onnx(net, onnx_input_shape(net), dst, dynamic_batch=True)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detector", type=Path, help="a detector checkpoint (best.pt)")
    parser.add_argument("--reid", type=Path, help="re-ID weights (reid.pt)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the fp16 files (must exist)")
    parser.add_argument("--suffix", default="fold3", help="name suffix, e.g. the validation fold")
    parser.add_argument("--onnx", action="store_true", help="write float32 ONNX graphs instead of fp16 .pt")
    parser.add_argument(
        "--image-size", type=input_size, default="640x480", help="detector ONNX input WxH (or S), pixels"
    )
    args = parser.parse_args(argv)
    written = []
    if args.detector and args.onnx:
        name = f"detector_yolov5s_{args.suffix}_{args.image_size[1]}x{args.image_size[0]}.onnx"
        written.append(export_detector_onnx(args.detector, args.out / name, image_size=args.image_size))
    elif args.detector:
        written.append(export_detector(args.detector, args.out / f"detector_yolov5s_{args.suffix}.pt"))
    if args.reid:
        name = f"reid_{args.suffix}.{'onnx' if args.onnx else 'pt'}"
        written.append((export_reid_onnx if args.onnx else export_reid)(args.reid, args.out / name))
    sizes = ", ".join(f"{path.name} {path.stat().st_size / 1e6:.1f} MB" for path in written)
    cli.print_summary(
        "export_weights", sizes or "nothing to export (give --detector or --reid)", args.out, None
    )


if __name__ == "__main__":
    cli.report_errors(main)
