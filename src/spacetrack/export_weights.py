"""Shrink trained weights for shipping: the detector's EMA weights and the re-ID network in fp16.

    python -m spacetrack.export_weights --detector outputs/train/<run>/weights/best.pt \\
        --reid outputs/train_reid/space_default/fold3/reid.pt --out weights/

The detector file keeps what `spacetrack.engine.checkpoint.load_detector` needs (`arch`, `ema`) plus the
training settings and history; optimiser state and the raw weights are dropped. Both loaders cast the
fp16 tensors back to the model's float32 on load.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from spacetrack.engine.checkpoint import load_checkpoint
from spacetrack.io import atomic_path, load_torch_file
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


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--detector", type=Path, help="a detector checkpoint (best.pt)")
    parser.add_argument("--reid", type=Path, help="re-ID weights (reid.pt)")
    parser.add_argument("--out", type=Path, required=True, help="folder for the fp16 files (must exist)")
    parser.add_argument("--suffix", default="fold3", help="name suffix, e.g. the validation fold")
    args = parser.parse_args(argv)
    if args.detector:
        path = export_detector(args.detector, args.out / f"detector_yolov5s_{args.suffix}.pt")
        print(f"{path}: {path.stat().st_size / 1e6:.1f} MB")
    if args.reid:
        path = export_reid(args.reid, args.out / f"reid_{args.suffix}.pt")
        print(f"{path}: {path.stat().st_size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
