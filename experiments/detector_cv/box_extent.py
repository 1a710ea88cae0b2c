"""Why a visible target counts as missed: no box near it, a box that covers only part of it, or a box of
the wrong class.

For each scored piece of a detector study (`run.py`'s `results/<variant>_fold<k>.json`, whose MLflow run
this store holds), the same detector runs again over the same validation frames, and every target is
put in one of these groups by the detections scoring >= 0.5 (the paper's `min_confidence`):

- `found`: a detection of its class at IoU >= 0.5 (what `recall_at_score` counts);
- `wrong_class`: found at IoU >= 0.5 only by a detection of another class;
- `partial`: no detection at IoU >= 0.5, but one at IoU >= 0.1, claimed by this target or not (a box
  around part of the target, or around more than it: a neighbour too); for these the study also records how much of the detection lies inside the
  target's box and the ratio of the two areas, which tells a box around the bright core of a faint
  target (inside, smaller) from a box that also takes in a neighbour (larger);
- `low_score`: none of these, but a detection scoring 0.1 to 0.5 at IoU >= 0.5 (any class): found by a
  lower `min_confidence`;
- `missed`: none of these.

Matching is one to one, greedy by score (`match_detections`), at IoU 0.5, 0.3 and 0.1, so the table also
gives the recall a looser overlap would give. Per scenario, pooled over the pieces.

    python experiments/detector_cv/box_extent.py --study wider_pretraining --variants yolov5s
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from spacetrack.data.yolo_dataset import collate
from spacetrack.engine.boxes import xywh_to_xyxy
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.metrics import box_iou, claimed_targets
from spacetrack.engine.nms import non_max_suppression
from spacetrack.io import atomic_write_text

_spec = importlib.util.spec_from_file_location("detector_cv_run", Path(__file__).resolve().parent / "run.py")
cv = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cv)

MIN_SCORE = 0.5
IOUS = np.array([0.5, 0.3, 0.1])
GROUPS = ("found", "wrong_class", "partial", "low_score", "missed")
LOW_SCORE = 0.1


def classify(det: np.ndarray, gt_boxes: np.ndarray, gt_classes: np.ndarray) -> dict[str, list]:
    """The group (see GROUPS) of each target of one image, and for the `partial` ones the share of the
    nearest detection's area inside the target's box and its area over the target's.

    `det` (n, 6) rows `x1, y1, x2, y2, score, class` (any scores: those below MIN_SCORE are dropped);
    `gt_boxes` (m, 4) xyxy, `gt_classes` (m,). Returns {"groups": [m names], "inside": [...],
    "area_ratio": [...]} (the last two one value per `partial` target)."""
    low = det[(det[:, 4] >= LOW_SCORE) & (det[:, 4] < MIN_SCORE)]
    det = det[det[:, 4] >= MIN_SCORE]
    m = len(gt_boxes)
    out: dict[str, list] = {"groups": [], "inside": [], "area_ratio": []}
    if m == 0:
        return out

    def found_by(classes: np.ndarray, gt: np.ndarray) -> np.ndarray:
        """(m, len(IOUS)) bool: is each target claimed by a detection at each IoU (one to one)?"""
        claimed = np.zeros((m, len(IOUS)), dtype=bool)
        claims = claimed_targets(det[:, :4], det[:, 4], classes, gt_boxes, gt, iou_thresholds=IOUS)
        for j in range(len(IOUS)):
            claimed[claims[:, j][claims[:, j] >= 0], j] = True
        return claimed

    same_class = found_by(det[:, 5], gt_classes)
    any_class = found_by(np.zeros(len(det)), np.zeros(m))
    overlap = box_iou(det[:, :4], gt_boxes)
    low_overlap = box_iou(low[:, :4], gt_boxes)
    for g in range(m):
        if same_class[g, 0]:
            out["groups"].append("found")
        elif any_class[g, 0]:
            out["groups"].append("wrong_class")
        elif len(det) and overlap[:, g].max() >= IOUS[-1]:
            out["groups"].append("partial")
            d = det[int(overlap[:, g].argmax()), :4]
            t = gt_boxes[g]
            inter = np.clip(np.minimum(d[2:], t[2:]) - np.maximum(d[:2], t[:2]), 0, None).prod()
            area_d = max(float(np.prod(d[2:] - d[:2])), 1e-9)
            out["inside"].append(float(inter / area_d))
            out["area_ratio"].append(area_d / max(float(np.prod(t[2:] - t[:2])), 1e-9))
        elif len(low) and low_overlap[:, g].max() >= IOUS[0]:
            out["groups"].append("low_score")
        else:
            out["groups"].append("missed")
    out["recall_any"] = any_class.sum(axis=0).tolist()
    return out


def summarise(parts: list[dict]) -> dict:
    """Counts and shares of GROUPS, class-agnostic recall at each of IOUS, and the medians of the
    partial boxes' `inside` and `area_ratio`, from `classify` results pooled."""
    groups = [g for p in parts for g in p["groups"]]
    n = len(groups)
    inside = [v for p in parts for v in p["inside"]]
    ratio = [v for p in parts for v in p["area_ratio"]]
    recall_any = np.sum([p.get("recall_any", [0] * len(IOUS)) for p in parts], axis=0) if parts else []
    return {
        "targets": n,
        **{g: groups.count(g) for g in GROUPS},
        **{
            f"recall_any_{iou:.1f}": (float(r) / n if n else 0.0)
            for iou, r in zip(IOUS, recall_any, strict=True)
        },
        "partial_inside_median": float(np.median(inside)) if inside else None,
        "partial_area_ratio_median": float(np.median(ratio)) if ratio else None,
        "partial_smaller_share": float(np.mean(np.array(ratio) < 1)) if ratio else None,
    }


@torch.no_grad()
def study_piece(cfg, weights: Path, frame_stride: int) -> dict[str, list[dict]]:
    """Per scenario the `classify` result of each validation frame of `cfg.fold` (every
    `frame_stride`-th, as `run.score` takes them)."""
    model = load_detector(weights).eval()
    out: dict[str, list[dict]] = {}
    for name, data in cv.validation_sets(cfg, frame_stride)[1].items():
        for images, targets in DataLoader(data, batch_size=4, collate_fn=collate):
            x = images.to(model.stride.device).float() / 255
            detections = non_max_suppression(model.detect.decode(model(x)), **cv.NMS)
            size = torch.tensor(x.shape[2:][::-1] * 2, dtype=torch.float32)
            for i, det in enumerate(detections):
                mine = targets[targets[:, 0] == i]
                gt = (xywh_to_xyxy(mine[:, 2:6]) * size).numpy()
                out.setdefault(name, []).append(classify(det.cpu().numpy(), gt, mine[:, 1].numpy()))
    return out


def table(rows: dict[str, dict]) -> str:
    """Markdown of the per-scenario summaries."""
    lines = [
        "| scenario | targets | found | wrong class | partial | low score | missed | any class at IoU 0.5 / 0.3 / 0.1 "
        "| partial: median share inside / area ratio, share smaller |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, s in rows.items():
        n = max(s["targets"], 1)
        share = " | ".join(f"{s[g] / n:.3f}" for g in GROUPS)
        recall = " / ".join(f"{s[f'recall_any_{iou:.1f}']:.3f}" for iou in IOUS)
        partial = (
            "-"
            if s["partial_inside_median"] is None
            else f"{s['partial_inside_median']:.2f} / {s['partial_area_ratio_median']:.2f}, "
            f"{s['partial_smaller_share']:.2f}"
        )
        lines.append(f"| {name} | {s['targets']} | {share} | {recall} | {partial} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--study", default="wider_pretraining", help="folder of the study beside this file")
    parser.add_argument("--variants", default="yolov5s", help="comma-separated: " + ", ".join(cv.VARIANTS))
    parser.add_argument("--folds", type=int, nargs="+", default=list(range(9)))
    parser.add_argument("--frame-stride", type=int, default=2, help="every n-th validation frame, as run.py")
    args = parser.parse_args()
    out = cv.HERE / args.study
    for slug in args.variants.split(","):
        pooled: dict[str, list[dict]] = {}
        folds = []
        for fold in args.folds:
            path = out / "results" / f"{slug}_fold{fold}.json"
            if not path.is_file():
                continue
            result = json.loads(path.read_text())
            cfg = cv.variant_config(slug, fold, result["overrides"], out)
            found = cv.matching_run(cfg)
            if found is None or found[0] != result["run_id"]:
                print(f"{path}: its MLflow run is not in this store; skipped")
                continue
            for name, parts in study_piece(cfg, found[2], args.frame_stride).items():
                pooled.setdefault(name, []).extend(parts)
            folds.append(fold)
            print(f"{slug} fold {fold} done")
        if not folds:
            continue
        rows = {"all": summarise([p for parts in pooled.values() for p in parts])}
        rows |= {name: summarise(parts) for name, parts in sorted(pooled.items())}
        report = {"variant": cv.VARIANTS[slug][0], "folds": folds, "min_score": MIN_SCORE, "scenarios": rows}
        atomic_write_text(out / f"box_extent_{slug}.json", json.dumps(report, indent=2) + "\n")
        atomic_write_text(
            out / f"box_extent_{slug}.md",
            f"{cv.VARIANTS[slug][0]}, folds {','.join(map(str, folds))}, detections scoring >= {MIN_SCORE} "
            f"(`box_extent.py`): each visible target's share of the groups, per scenario.\n\n" + table(rows),
        )
        print(table(rows))


if __name__ == "__main__":
    main()
