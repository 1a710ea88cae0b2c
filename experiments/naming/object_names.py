"""What detectors call one object: in every labelled frame of it (the step given), the class of the
detection that boxes it best (score >= 0.25, IoU >= 0.45 with its truth box, whatever the class: the
pairing of the confusion matrices), or `missed`.

    python experiments/naming/object_names.py data/space_default_psf seq_031_dim 2 \\
        start=weights/yolov5s_pretrained.pt tuned=outputs/detector_cv/side_lit/yolov5s_fold2/weights/best.pt \\
        --out experiments/detector_cv/side_lit/seq_031_dim_rocket_body.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from spacetrack.data.layout import load_manifest
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.inference import detect
from spacetrack.engine.metrics import box_iou
from spacetrack.io import atomic_write_text

CONF, IOU = 0.25, 0.45


def truth_rows(root: Path, sequence: str, object_id: int) -> np.ndarray:
    """(n, 7) `frame, x1, y1, x2, y2, class, visibility` of the object's labelled rows in gt/gt.txt."""
    path = root / sequence / "gt" / "gt.txt"
    gt = np.loadtxt(path, delimiter=",", ndmin=2)
    rows = gt[(gt[:, 1] == object_id) & (gt[:, 6] > 0)]
    if not len(rows):
        raise ValueError(f"{path}: object {object_id} has no labelled row")
    boxes = np.c_[rows[:, 2:4], rows[:, 2:4] + rows[:, 4:6]]
    return np.c_[rows[:, 0], boxes, rows[:, 7], rows[:, 8]]


def names(model, root: Path, sequence: str, rows: np.ndarray, names_: list[str]) -> dict:
    images = sorted((root / sequence / "img").iterdir())
    tally = dict.fromkeys([*names_, "missed"], 0)
    for frame, *box, _, _ in rows:
        image = np.asarray(Image.open(images[int(frame) - 1]).convert("RGB"))
        det = detect(model, [image], conf_threshold=CONF)[0]
        iou = box_iou(np.asarray([box]), det[:, :4])[0] if len(det) else np.zeros(0)
        tally[names_[int(det[iou.argmax(), 5])] if len(iou) and iou.max() >= IOU else "missed"] += 1
    return tally


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("sequence")
    parser.add_argument("object_id", type=int)
    parser.add_argument("detectors", nargs="+", help="label=path of a detector checkpoint or weights file")
    parser.add_argument("--step", type=int, default=1, help="every step-th labelled frame")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    class_names = list(load_manifest(args.dataset)["class_names"])
    rows = truth_rows(args.dataset, args.sequence, args.object_id)[:: args.step]
    record = {
        "dataset": args.dataset.as_posix(),
        "sequence": args.sequence,
        "object_id": args.object_id,
        "class": class_names[int(rows[0, 5])],
        "frames": len(rows),
        "median_visibility": round(float(np.median(rows[:, 6])), 3),
        "pairing": f"best-IoU detection at score >= {CONF}, IoU >= {IOU}, any class",
        "detectors": {},
    }
    for spec in args.detectors:
        label, path = spec.split("=", 1)
        model = load_detector(path).float()
        record["detectors"][label] = {
            "path": path,
            "named": names(model, args.dataset, args.sequence, rows, class_names),
        }
        print(label, record["detectors"][label]["named"])
    atomic_write_text(args.out, json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
