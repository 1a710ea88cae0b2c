"""Detector training throughput: float32 against bfloat16 autocast, NCHW against channels-last (NHWC)
memory layout, the whole network trained against a frozen backbone (`train.freeze`), and decoded-frame
crops against a JPEG decode per sample, in one run -> reports/train.json and reports/train.md.

    python benchmarks/bench_train.py                 # YOLOv5s, 256-px crops, batch 8, 1 and 2 threads
    python benchmarks/bench_train.py --steps 3 --threads 1
    python benchmarks/bench_train.py --precisions float32 --report train_no_bf16   # -> reports/train_no_bf16.*
    python benchmarks/bench_train.py --precisions float32 --threads 2 --models yolov5s yolov5s_gam \
        --freeze 2 3 --report train_gam_no_bf16          # YOLOv5s against YOLOv5s + GAM, rows alternating

Training step: forward, YOLO loss, backward and SGD step on a batch of real crops (random ones where
the dataset is not built). bfloat16 runs through `torch.autocast("cpu", dtype=torch.bfloat16)`; the
report says whether this CPU computes bfloat16 natively (`native_bfloat16`, as the trainer detects it:
only then does the trainer use it). Channels-last puts the model and each batch in NHWC layout, as the
trainer does with `train.trainer.channels_last: true` (the default). A frozen backbone (`--freeze`: the
first k blocks, a NHWC row for each k) is trained as `train.freeze=k` trains it: backpropagation stops
at the first trained block. The last column is each row's step time over the first precision's NCHW
row of the same model (float32 unless `--precisions` leaves it out). `--models` times YOLOv5s and YOLOv5s
+ GAM (after SPPF, `model=yolov5s_gam`) in one run. Steps of every contender alternate, so load changes
hit all alike.
Data: samples per second of `CropDataset` reading the `FrameStore` cache against the whole-frame
`YoloDataset` that decodes the JPEG (and letterboxes it) for every sample.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from common import interleaved_samples, markdown_table, summarize, write_report
from spacetrack.data.crops import CropDataset
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.data.yolo_dataset import YoloDataset, build_augmentation, collate
from spacetrack.engine.loss import YoloLoss
from spacetrack.engine.optim import build_optimizer
from spacetrack.engine.precision import native_bfloat16
from spacetrack.enhance import DwtHsvEnhancer
from spacetrack.models.yolo import YOLOv5

PRECISIONS = {"float32": None, "bfloat16": torch.bfloat16}  # autocast dtype (None: none)
MODELS = {"yolov5s": None, "yolov5s_gam": "after_sppf"}  # name (conf/model) -> its GAM position
AUGMENT = {"hue": 5, "saturation": 30, "value": 30, "fliplr": 0.5, "flipud": 0.5, "scale": 0.25,
           "translate": 0.0, "fill": 0}  # fmt: skip


def crop_data(root: Path, size: int) -> CropDataset | None:
    if not (root / "manifest.json").is_file():
        return None
    train, _ = split_sequences(load_manifest(root), 3)
    store = FrameStore(root=root)
    return CropDataset(root=root, sequences=train, num_classes=3, store=store, crop_size=size,
                       frame_stride=4, augment=build_augmentation(**AUGMENT))  # fmt: skip


def training_step(
    size: int,
    batch: int,
    data: CropDataset | None,
    dtype: torch.dtype | None,
    channels_last: bool = False,
    freeze: int = 0,
    model_name: str = "yolov5s",
):
    """A callable running one training step of a fresh YOLOv5s (`model_name`, a key of MODELS) in `dtype`
    autocast (None: float32), in channels-last layout or not, its first `freeze` backbone blocks frozen."""
    torch.manual_seed(0)
    model = YOLOv5(num_classes=3, gam_position=MODELS[model_name]).train()
    model.freeze_backbone(freeze)
    layout = torch.channels_last if channels_last else torch.contiguous_format
    model.to(memory_format=layout)
    loss_fn = YoloLoss(anchors=model.detect.anchors, strides=model.stride, num_classes=3, image_size=size)
    optimizer = build_optimizer(model, lr0=0.001, momentum=0.9, weight_decay=5e-4)
    if data is not None:
        images, targets = collate([data[i] for i in range(batch)])
    else:
        images = torch.randint(0, 255, (batch, 3, size, size), dtype=torch.uint8)
        targets = torch.tensor([[i, i % 3, 0.5, 0.5, 0.1, 0.1] for i in range(batch)])

    def step() -> None:
        x = (images.float() / 255).contiguous(memory_format=layout)
        with torch.autocast("cpu", dtype=dtype or torch.bfloat16, enabled=dtype is not None):
            raw = model(x)
        loss, _ = loss_fn([p.float() for p in raw], targets)
        loss.backward()
        optimizer.step()
        optimizer.zero_grad()

    return step


def data_rates(root: Path, size: int, samples: int) -> list[list[object]]:
    """Samples/s of crops from the decoded cache and of whole frames decoded (and enhanced) per sample,
    each timed on a second pass over the same random samples (the first warms the page cache)."""
    crops = crop_data(root, size)
    if crops is None:
        return []
    train, _ = split_sequences(load_manifest(root), 3)
    letterboxed = {"root": root, "sequences": train, "num_classes": 3, "image_size": 320, "frame_stride": 4,
                   "augment": build_augmentation(**AUGMENT | {"fill": 114})}  # fmt: skip
    enhancer = DwtHsvEnhancer()
    contenders = {
        "crops from the decoded-frame cache": crops,
        "JPEG decode per sample (320 letterbox)": YoloDataset(**letterboxed),
        "JPEG decode + DWT/HSV per sample (320 letterbox)": YoloDataset(**letterboxed, enhancer=enhancer),
    }
    rows = []
    for name, data in contenders.items():
        picks = [int(i) for i in np.random.default_rng(0).integers(len(data), size=samples)]
        for n in range(2):
            started = time.perf_counter()
            for i in tqdm(picks, desc=f"{name[:30]} ({n + 1}/2)", unit="sample", leave=False):
                data[i]
        rows.append([name, samples / (time.perf_counter() - started)])
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--size", type=int, default=256, help="crop side, pixels")
    parser.add_argument("--batch", type=int, default=8)
    parser.add_argument("--steps", type=int, default=3, help="timed steps per precision and thread count")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--data", type=Path, default=Path("data/space_default"))
    parser.add_argument("--samples", type=int, default=100, help="data samples timed per contender")
    parser.add_argument(
        "--freeze", type=int, nargs="*", default=[2, 5], help="backbone blocks frozen, a row each"
    )
    parser.add_argument("--precisions", nargs="+", choices=list(PRECISIONS), default=list(PRECISIONS))
    parser.add_argument("--models", nargs="+", choices=list(MODELS), default=["yolov5s"])
    parser.add_argument("--report", default="train", help="reports/<name>.json and .md")
    args = parser.parse_args()
    if not args.report.isidentifier():
        parser.error(
            f"--report {args.report!r}: a plain name (letters, digits, underscores), written under reports/"
        )
    crops = crop_data(args.data, args.size)
    rows, record = (
        [],
        {"size": args.size, "batch": args.batch, "native_bfloat16": native_bfloat16(), "rows": []},
    )
    for threads in tqdm(args.threads, desc="thread counts", unit="setting"):
        torch.set_num_threads(threads)
        settings = [(layout, 0) for layout in ("NCHW", "NHWC")] + [("NHWC", k) for k in args.freeze if k]
        calls = {
            f"{model} {precision} {layout} {freeze}": training_step(
                args.size, args.batch, crops, dtype, layout == "NHWC", freeze, model
            )
            for model in args.models
            for precision, dtype in PRECISIONS.items()
            if precision in args.precisions
            for layout, freeze in settings
        }
        wall, _ = interleaved_samples(calls, repeats=args.steps)
        bases = {
            m: summarize(wall[f"{m} {args.precisions[0]} NCHW 0"], scale=1.0)["median"] for m in args.models
        }
        for name, samples in wall.items():
            model, precision, layout, freeze = name.split()
            median = summarize(samples, scale=1.0)["median"]
            entry = {"model": model, "precision": precision, "layout": layout, "frozen_blocks": int(freeze),
                     "threads": threads, "img_per_s": args.batch / median, "step_s": summarize(samples, scale=1.0),
                     "x_float32_time": median / bases[model]}  # fmt: skip
            record["rows"].append(entry)
            cells = [precision, layout, freeze, threads, entry["img_per_s"], median, entry["x_float32_time"]]
            rows.append(([model] if len(args.models) > 1 else []) + cells)
    data = data_rates(args.data, args.size, samples=args.samples)
    record["data"] = [{"source": r[0], "samples_per_s": r[1]} for r in data]
    md = (
        f"# Detector training throughput (CPU)\n\n{' and '.join(args.models)}, batch {args.batch} of "
        f"{args.size}-px crops "
        f"({'real crops of ' + str(args.data) if crops else 'random images'}), forward + loss + backward + "
        f"SGD step, medians of {args.steps} steps per row, contenders alternating. This CPU computes "
        f"bfloat16 natively: **{'yes' if record['native_bfloat16'] else 'no'}** (the trainer uses "
        "bfloat16 only where it does; elsewhere it is emulated). Layout NHWC: channels-last, the "
        "trainer's default. Frozen: backbone blocks not trained (`train.freeze`; 0: the whole network "
        "trains, the default).\n\n"
        + markdown_table(
            (["model"] if len(args.models) > 1 else [])
            + [
                "precision",
                "layout",
                "frozen",
                "threads",
                "img/s",
                "s per step",
                f"x {args.precisions[0]} NCHW time",
            ],
            rows,
        )
    )
    if data:
        md += (
            f"\nData pipeline, one process, {args.samples} random samples (second pass):\n\n"
            + markdown_table(["source", "samples/s"], data)
        )
    json_path, md_path = write_report(args.report, record, md)
    print(md)
    print(f"spacetrack bench_train: files: {json_path} {md_path}")


if __name__ == "__main__":
    main()
