"""Does a detection's past help name and score it? Causal temporal rescoring of a study's detectors.

A video detector can carry what it saw on the previous frames: each detection of frame t is linked to
one of frame t-1 (IoU >= `LINK_IOU`; detections taken best score first, each taking the unlinked
predecessor with the highest rescored score) and its objectness and class probabilities are smoothed
along the link,

    objectness_t <- a_obj * objectness_t + (1 - a_obj) * objectness_{t-1}   (rescored)
    classes_t    <- the objectness-weighted mean of classes_t (weight a_cls) and classes_{t-1} (1 - a_cls)

then scored `objectness x best class probability` and named by that class, as the detector is. Only past
frames are used, so it could run online in the pipeline. Each setting is a pair (a_obj, a_cls); (1, 1)
is the detector alone and must reproduce the piece's recorded scores (checked).

Each piece of a study (`run.py`'s `<study>/results/<variant>_fold<k>.json`) is detected on every frame of
its fold's validation sequences with the best weights of its own MLflow run (`run.py`'s NMS: score >=
0.001, IoU 0.6, 300 boxes), rescored, and scored as `run.py` scores it: every 2nd frame, mAP@0.5,
mAP@0.5:0.95 and recall at score >= 0.5, with its class and with every class as one, overall and per
scenario. Results go to `<out>/results.json` and `<out>/results.md`.

    python experiments/detector_cv/temporal_rescoring.py --study float32_gam --variant dwt_hsv_gam \
        --folds 0 2 3 6 --out experiments/detector_cv/temporal_rescoring
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

import numpy as np
import torch
from torch.utils.data import DataLoader

from spacetrack.data.yolo_dataset import YoloDataset, collate
from spacetrack.engine.boxes import xywh_to_xyxy
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.metrics import box_iou, detection_metrics, match_detections
from spacetrack.engine.nms import non_max_suppression
from spacetrack.io import atomic_write_text

HERE = Path(__file__).resolve().parent
_spec = importlib.util.spec_from_file_location("detector_cv_run", HERE / "run.py")
cv = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(cv)

LINK_IOU = 0.5
# name -> (a_obj, a_cls): the weight of the current frame in each smoothing; 1 keeps the frame's own value
SETTINGS = {
    "detector alone": (1.0, 1.0),
    "objectness 0.7": (0.7, 1.0),
    "objectness 0.5": (0.5, 1.0),
    "classes 0.5": (1.0, 0.5),
    "classes 0.2": (1.0, 0.2),
    "both 0.5": (0.5, 0.5),
}
GROUPS = ("all", "dim", "strong_light")
SCORED = ("map50", "map50_95", "recall_at_score")
# the detector alone may differ from the recorded piece by batching (other frames share its batches)
REPRODUCE_TOLERANCE = 0.003


@torch.no_grad()
def detect_sequence(model, data: YoloDataset, batch: int = 4) -> tuple[list[np.ndarray], list[tuple]]:
    """Per frame of `data` (in order), read once: its detections, an (n, 7 + C) array `x1, y1, x2, y2,
    score, class, objectness, p_1 .. p_C` (`non_max_suppression` with `probabilities`), and its truth,
    (boxes xyxy in pixels, classes)."""
    detections, truth = [], []
    for images, targets in DataLoader(data, batch_size=batch, collate_fn=collate):
        x = images.float() / 255
        found = non_max_suppression(model.predict(x).float(), **cv.NMS, probabilities=True)
        size = torch.tensor(x.shape[2:][::-1] * 2, dtype=torch.float32)
        for i, det in enumerate(found):
            mine = targets[targets[:, 0] == i]
            detections.append(det.numpy())
            truth.append(((xywh_to_xyxy(mine[:, 2:6]) * size).numpy(), mine[:, 1].numpy()))
    return detections, truth


def rescore(frames: list[np.ndarray], a_obj: float, a_cls: float) -> list[tuple[np.ndarray, ...]]:
    """(boxes, scores, classes) per frame of `frames` (`detect_sequence`'s), rescored along the links to
    the previous frame as the module docstring says."""
    previous = None  # (boxes, objectness, class probabilities) of frame t-1, rescored
    out = []
    for det in frames:
        boxes, obj, probs = det[:, :4], det[:, 6].copy(), det[:, 7:].copy()
        own_obj, own_probs = det[:, 6], det[:, 7:]
        if previous is not None and len(boxes) and len(previous[0]):
            iou = box_iou(boxes, previous[0])
            before = previous[1] * previous[2].max(axis=1)
            free = np.ones(len(before), dtype=bool)
            for i in np.argsort(-det[:, 4], kind="stable"):
                candidates = np.flatnonzero((iou[i] >= LINK_IOU) & free)
                if not len(candidates):
                    continue
                j = candidates[before[candidates].argmax()]
                free[j] = False
                obj[i] = a_obj * own_obj[i] + (1 - a_obj) * previous[1][j]
                now, then = a_cls * own_obj[i], (1 - a_cls) * previous[1][j]
                probs[i] = (now * own_probs[i] + then * previous[2][j]) / max(now + then, 1e-12)
        previous = (boxes, obj, probs)
        out.append((boxes, obj * probs.max(axis=1), probs.argmax(axis=1).astype(np.float64)))
    return out


def scores(
    detected: dict[str, list], truth: dict[str, list], scenario: dict[str, str], setting, frame_stride: int
) -> dict:
    """{group: {metric: value}} of one setting: class-aware `SCORED` and the same with every class as one
    (suffix `_any`), every `frame_stride`-th frame, per scenario and "all"."""
    pooled: dict[str, list] = {}
    for seq, frames in detected.items():
        for t, (boxes, score, cls) in list(enumerate(rescore(frames, *setting)))[::frame_stride]:
            gt, gt_cls = truth[seq][t]
            hit = match_detections(boxes, score, cls, gt, gt_cls)
            hit_any = match_detections(boxes, score, np.zeros(len(cls)), gt, np.zeros(len(gt_cls)))
            for group in (scenario[seq], "all"):
                pooled.setdefault(group, []).append((hit, hit_any, score, cls, gt_cls))
    out = {}
    for group, parts in pooled.items():
        hit, hit_any, score, cls, truth = (np.concatenate(a) for a in zip(*parts, strict=True))
        named = detection_metrics(hit, score, cls, truth)
        anyclass = detection_metrics(hit_any, score, np.zeros_like(cls), np.zeros_like(truth))
        out[group] = {k: float(named[k]) for k in SCORED} | {f"{k}_any": float(anyclass[k]) for k in SCORED}
    return out


def fold_rows(study: Path, variant: str, fold: int, frame_stride: int) -> dict | None:
    """Every setting's scores of one piece, after checking the detector alone against the piece; None
    where this MLflow store does not hold the piece's run (trained on another machine)."""
    piece = json.loads((study / "results" / f"{variant}_fold{fold}.json").read_text())
    cfg = cv.variant_config(variant, fold, piece["overrides"], study)
    found = cv.matching_run(cfg)
    if found is None or found[0] != piece["run_id"]:
        return None
    model = load_detector(found[2])
    model.eval()
    _, sets, scenario = cv.validation_sets(cfg, frame_stride=1, per_sequence=True)
    detected, truth = {}, {}
    for seq, data in sets.items():
        detected[seq], truth[seq] = detect_sequence(model, data)
    rows = {name: scores(detected, truth, scenario, s, frame_stride) for name, s in SETTINGS.items()}
    alone = rows["detector alone"]["all"]
    for key in SCORED:
        if abs(alone[key] - piece["all"][key]) > REPRODUCE_TOLERANCE:
            raise SystemExit(
                f"{variant} fold {fold}: the detector alone scores {key} {alone[key]:.4f} here against "
                f"{piece['all'][key]:.4f} recorded: not the piece's detector or scoring"
            )
    return {"fold": fold, "variant": variant, "run_id": piece["run_id"], "settings": rows}


def cell(row: dict, group: str) -> str:
    if group not in row:
        return "-"
    r = row[group]
    return f"{r['map50']:.3f} / {r['recall_at_score']:.3f} ({r['map50_any']:.3f} / {r['recall_at_score_any']:.3f})"


def table(results: list[dict]) -> str:
    """Markdown: per fold and setting, mAP@0.5 / recall at score >= 0.5 (any class in brackets), and the
    means over the folds."""
    lines = [
        "mAP@0.5 / recall at score >= 0.5 with the class (with every class as one in brackets), every 2nd "
        "validation frame; settings (a_obj, a_cls) in `temporal_rescoring.py`.",
        "",
        "| fold | setting | all | dim | strong light |",
        "|---|---|---|---|---|",
    ]
    for result in results:
        for name, row in result["settings"].items():
            cells = " | ".join(cell(row, g) for g in GROUPS)
            lines.append(f"| {result['variant']} {result['fold']} | {name} | {cells} |")
    lines += ["", "Means over the folds that have the group:", "", "| setting | all | dim | strong light |",
              "|---|---|---|---|"]  # fmt: skip
    for name in SETTINGS:
        cells = []
        for group in GROUPS:
            rows = [r["settings"][name][group] for r in results if group in r["settings"][name]]
            mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0]} if rows else None
            cells.append(cell({group: mean}, group) if mean else "-")
        lines.append(f"| {name} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--study", required=True, help="a study folder under experiments/detector_cv")
    parser.add_argument("--variant", default="dwt_hsv_gam", choices=sorted(cv.VARIANTS))
    parser.add_argument("--folds", type=int, nargs="+", required=True)
    parser.add_argument("--frame-stride", type=int, default=2, help="score every n-th frame (run.py: 2)")
    parser.add_argument("--out", type=Path, default=HERE / "temporal_rescoring")
    args = parser.parse_args()
    study = HERE / args.study
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "results.json"
    results = json.loads(path.read_text()) if path.is_file() else []
    for fold in args.folds:
        row = fold_rows(study, args.variant, fold, args.frame_stride)
        if row is None:
            print(f"{args.variant} fold {fold}: skipped, this MLflow store does not hold its run")
            continue
        row["study"] = args.study
        results = [
            r for r in results if (r["study"], r["variant"], r["fold"]) != (args.study, args.variant, fold)
        ]
        results.append(row)
        results.sort(key=lambda r: (r["study"], r["variant"], r["fold"]))
        atomic_write_text(path, json.dumps(results, indent=1) + "\n")
        atomic_write_text(args.out / "results.md", table(results))
        print(
            f"{args.variant} fold {fold}: "
            + ", ".join(f"{n}: {cell(s, 'all')}" for n, s in row["settings"].items())
        )


if __name__ == "__main__":
    main()
