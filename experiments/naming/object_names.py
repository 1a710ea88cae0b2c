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

from spacetrack.data.layout import frame_paths, load_manifest, read_rgb
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.inference import detect
from spacetrack.engine.metrics import box_iou
from spacetrack.io import atomic_write_text
from spacetrack.reid.dataset import collect_crops

CONF, IOU = 0.25, 0.45


def truth_rows(root: Path, sequence: str, object_id: int) -> np.ndarray:
    """(n, 7) `frame, x1, y1, x2, y2, class, visibility` of the object's labelled rows in gt/gt.txt."""
    table = collect_crops(root, [sequence], min_visibility=0.0, min_box_size=0.0, include_static=False)
    if (sequence, object_id) not in table.names:
        raise ValueError(f"{root / sequence / 'gt' / 'gt.txt'}: object {object_id} has no labelled row")
    mine = table.identity == table.names.index((sequence, object_id))
    tl, wh = table.box[mine, :2], table.box[mine, 2:]
    return np.c_[table.frame[mine], tl, tl + wh, table.object_class[mine], table.visibility[mine]]


def names(model, images: list[np.ndarray], boxes: np.ndarray, class_names: list[str]) -> dict:
    """{class or `missed`: frames} over `images`, each holding the object at its xyxy row of `boxes`."""
    tally = dict.fromkeys([*class_names, "missed"], 0)
    for image, box in zip(images, boxes, strict=True):
        det = detect(model, [image], conf_threshold=CONF)[0]
        iou = box_iou(box[None], det[:, :4])[0] if len(det) else np.zeros(0)
        tally[class_names[int(det[iou.argmax(), 5])] if len(iou) and iou.max() >= IOU else "missed"] += 1
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
    paths = frame_paths(args.dataset, args.sequence)
    images = [read_rgb(paths[int(frame) - 1]) for frame in rows[:, 0]]  # read once for every detector
    for spec in args.detectors:
        label, path = spec.split("=", 1)
        model = load_detector(path).float()
        named = names(model, images, rows[:, 1:5], class_names)
        record["detectors"][label] = {"path": path, "named": named}
        print(label, record["detectors"][label]["named"])
    atomic_write_text(args.out, json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
