"""Which box a detector draws on a faint target: the seen truth's, or the whole outline's.

The seen truth (`data.truth=seen`) frames only the pixels of an object that stand three times above the
noise; the silhouette truth (`data.truth=silhouette`) frames its whole outline. Both are rendered from
one plan, so the same seed gives byte-identical images under either and only the labels differ. This
script runs one detector checkpoint over one sequence (every `--frame-stride`-th frame, detections
scoring >= `--min-score`, every class as one) and, for each target visible in the seen truth, takes
the best IoU of any detection with its seen box and with its silhouette box. A target missed at IoU 0.5
by its seen box but matched by its silhouette box is one the detector boxed whole.

    python -m spacetrack.build_data data.name=space_default_silhouette data.truth=silhouette
    python experiments/detector_cv/extent_vs_silhouette.py --weights outputs/detector_cv/without/yolov5s_fold0/weights/best.pt \
        --sequence seq_019_dim --out experiments/detector_cv/exposure/float32/without/extent_seq_019_dim.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from spacetrack.data.layout import BOX, CONF, FRAME, ID, frame_paths, read_mot, read_rgb
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.inference import detect
from spacetrack.engine.plots import xyxy_to_tlwh
from spacetrack.io import atomic_write_text
from spacetrack.tracking.iou_matching import iou_matrix


def gt_rows(root: Path, sequence: str) -> np.ndarray:
    try:
        return read_mot(root / sequence / "gt" / "gt.txt")
    except FileNotFoundError as err:
        raise SystemExit(f"{err} (render the dataset first)") from None


def best_ious(detections: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Per `tlwh` box the best IoU of any `x1, y1, x2, y2, ...` detection (0 without one)."""
    if not len(detections) or not len(boxes):
        return np.zeros(len(boxes))
    return iou_matrix(boxes, xyxy_to_tlwh(detections[:, :4])).max(axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--weights", required=True, help="a detector checkpoint (best.pt or an exported file)"
    )
    parser.add_argument("--sequence", required=True)
    parser.add_argument("--seen", default="data/space_default_psf", help="the dataset with the seen truth")
    parser.add_argument(
        "--silhouette", default="data/space_default_silhouette", help="the same, silhouette truth"
    )
    parser.add_argument("--frame-stride", type=int, default=2)
    parser.add_argument("--min-score", type=float, default=0.5)
    parser.add_argument("--out", help="JSON file for the result")
    args = parser.parse_args()

    seen_root, silhouette_root = Path(args.seen), Path(args.silhouette)
    seen, silhouette = gt_rows(seen_root, args.sequence), gt_rows(silhouette_root, args.sequence)
    outline = {(int(r[FRAME]), int(r[ID])): r[BOX] for r in silhouette}
    model = load_detector(args.weights)
    images = list(enumerate(frame_paths(seen_root, args.sequence), start=1))
    seen_iou, whole_iou, area_ratio = [], [], []
    for frame, path in images[:: args.frame_stride]:
        targets = seen[(seen[:, FRAME] == frame) & (seen[:, CONF] > 0)]
        if not len(targets):
            continue
        detections = detect(model, [read_rgb(path)], conf_threshold=args.min_score, iou_threshold=0.6)[0]
        whole = np.array([outline.get((frame, int(k)), np.zeros(4)) for k in targets[:, ID]])
        seen_iou.extend(best_ious(detections, targets[:, BOX]))
        whole_iou.extend(best_ious(detections, whole))
        area_ratio.extend(whole[:, 2] * whole[:, 3] / np.maximum(targets[:, 4] * targets[:, 5], 1e-9))
    s, w = np.array(seen_iou), np.array(whole_iou)
    result = {
        "weights": args.weights,
        "sequence": args.sequence,
        "frame_stride": args.frame_stride,
        "min_score": args.min_score,
        "targets": len(s),
        "median_outline_to_seen_area": float(np.median(area_ratio)) if area_ratio else None,
    }
    for t in (0.5, 0.3):
        result[f"found_seen_iou{t}"] = float(np.mean(s >= t))
        result[f"found_outline_iou{t}"] = float(np.mean(w >= t))
        result[f"found_either_iou{t}"] = float(np.mean((s >= t) | (w >= t)))
    missed = s < 0.5
    result["missed_seen_iou0.5"] = int(missed.sum())
    result["of_them_outline_iou0.5"] = int((w[missed] >= 0.5).sum())
    text = json.dumps(result, indent=2) + "\n"
    if args.out:
        atomic_write_text(Path(args.out), text)
    print(text, end="")


if __name__ == "__main__":
    main()
