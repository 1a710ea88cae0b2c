"""Silhouette truth against seen truth: how much of the detector's shortfall is boxes the image does not show.

`data.truth=silhouette` labels each target with the box of its whole silhouette, lit or not; a target
in its own shadow is black on black there (`ambient` 0), yet its truth box still frames the dark part.
`data.truth=seen` (the default) renders the same frames (same seed, identical images) with boxes of
only the pixels the camera shows above its noise. This script compares the two, each rendered under a
name of its own:

1. `labels.json`: per scenario and sequence, how many silhouette boxes the seen truth shrinks below half
   their area (IoU < 0.5: a detector framing what it sees cannot match them) or hides altogether.
2. `results/<truth>_fold<k>.json` (`<truth>_<variant>_fold<k>.json` for another variant than plain
   YOLOv5s): each fold's detector (`<detectors>/<variant>_fold<k>/weights/best.pt`, trained on the
   silhouette or the seen truth, as its recorded settings say) scored against both truths exactly as
   `experiments/detector_cv/` scores it (every 2nd validation frame at 640x480: mAP@0.5, mAP@0.5:0.95,
   recall at score >= 0.5, overall and per scenario), and tracked against both with Table 4's rows of
   the paper's settings: `yolo_deepsort_paper` (`gam_deepsort_paper` for YOLOv5s + GAM on DWT/HSV) and
   `gt_deepsort_paper`.

    python -m spacetrack.build_data data.name=space_default_silhouette data.truth=silhouette
    python -m spacetrack.build_data data.name=space_default_seen data.truth=seen
    python experiments/seen_truth/run.py --folds 0 2 3 6 7 \\
        --detectors outputs/detector_cv/longer_pretraining              # trained on the silhouettes
    python experiments/detector_cv/run.py --folds 7 --variants yolov5s \\
        --out experiments/detector_cv/seen_truth -- data.name=space_default_seen   # make train on seen
    python experiments/seen_truth/run.py --folds 7 --detectors outputs/detector_cv/seen_truth
    python experiments/detector_cv/run.py --folds 3 --variants dwt_hsv_gam \
        --out experiments/detector_cv/seen_truth -- data.name=space_default_seen   # the paper's detector
    python experiments/seen_truth/run.py --folds 3 --variant dwt_hsv_gam \
        --detectors outputs/detector_cv/seen_truth
    python experiments/seen_truth/run.py --folds 3 --variant dwt_hsv_gam \
        --detectors outputs/detector_cv/seen_truth --add-rows gam_deepsort_original   # another Table 4 row

Each fold's piece is written as it finishes; `results.md` is rebuilt from every piece present.
"""

from __future__ import annotations

import argparse
import functools
import importlib.util
import json
import sys
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from torchvision.ops import box_iou

from spacetrack import track
from spacetrack.config import REPO_ROOT, compose_config
from spacetrack.data.layout import load_manifest, read_mot
from spacetrack.engine.checkpoint import peek_checkpoint
from spacetrack.io import atomic_write_text

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(REPO_ROOT / "experiments" / "detector_cv"))
import run as detector_cv  # noqa: E402  (experiments/detector_cv/run.py)

TRUTHS = {"silhouette": "space_default_silhouette", "seen": "space_default_seen"}  # the same frames
# Each detector variant's tracking rows (Table 4's): the paper's settings on its detections, then on
# ground-truth boxes.
ROWS = {
    "yolov5s": ("yolo_deepsort_paper", "gt_deepsort_paper"),
    "dwt_hsv_gam": ("gam_deepsort_paper", "gt_deepsort_paper"),
}
SHRUNK_IOU = 0.5
# what a tracked piece keeps of `spacetrack.track`'s metrics (the class accuracies: each track's voted class)
TRACK_METRICS = ("mota", "hota", "idf1", "idsw", "fp", "fn", "class_accuracy", "class_accuracy_frame")
OWN_REID = "+own_reid"  # suffix of a row tracked with the fold's own re-ID model instead of fold 3's


@functools.cache
def _table4_rows() -> dict:
    """Table 4's row settings (experiments/table4_mota/run.py), loaded once under another module name."""
    spec = importlib.util.spec_from_file_location("table4_run", REPO_ROOT / "experiments/table4_mota/run.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.ROWS


def label_statistics(data_root: Path) -> dict:
    """Per scenario and per sequence: the silhouette truth's shown target boxes, and the share of them the
    seen truth hides or shrinks below IoU 0.5 (moving targets, every frame)."""
    return truth_changes(*(data_root / name for name in TRUTHS.values()))


def truth_changes(silhouette: Path, seen: Path) -> dict:
    """`label_statistics` of any two renders of the same sequences: the boxes shown in the first
    (`silhouette`), and how many of them the second (`seen`) hides or moves below IoU 0.5."""
    manifest = load_manifest(silhouette)
    counts: dict[str, dict[str, int]] = defaultdict(lambda: defaultdict(int))
    per_sequence = {}
    for seq in manifest["sequences"]:
        a = read_mot(silhouette / seq["name"] / "gt" / "gt.txt")
        b = read_mot(seen / seq["name"] / "gt" / "gt.txt")
        if a.shape != b.shape or not np.array_equal(a[:, :2], b[:, :2]):
            raise ValueError(
                f"{seq['name']}: the two truths list other (frame, id) rows; render both from one seed"
            )
        shown = a[:, 6] > 0
        hidden = shown & (b[:, 6] == 0)
        iou = box_iou(_xyxy(a), _xyxy(b)).diagonal().numpy()
        shrunk = shown & ~hidden & (iou < SHRUNK_IOU)
        row = {"boxes": int(shown.sum()), "hidden": int(hidden.sum()), "shrunk": int(shrunk.sum())}
        per_sequence[seq["name"]] = row | {"scenario": seq["scenario"], "fold": seq["fold"]}
        for key in (seq["scenario"], "all"):
            for k, v in row.items():
                counts[key][k] += v
    return {
        "scenarios": {
            k: dict(v) | {"lost_share": (v["hidden"] + v["shrunk"]) / v["boxes"]} for k, v in counts.items()
        },
        "sequences": per_sequence,
    }


def _xyxy(rows: np.ndarray) -> torch.Tensor:
    box = torch.as_tensor(rows[:, 2:6], dtype=torch.float32)
    return torch.cat([box[:, :2], box[:, :2] + box[:, 2:]], dim=1)


def trained_on(weights: Path, data_root: Path) -> str:
    """Which truth `weights` was trained on: the study dataset whose content its run recorded
    (`data_content`); for runs made before runs recorded it, the dataset name they record (their
    settings' `data.truth` is the config default of their day, absent before the key existed, and need
    not be what the dataset was rendered with)."""
    settings = peek_checkpoint(weights)["settings"]
    content = settings.get("data_content")
    if content is None:
        data = settings["data"]
        return "seen" if data["name"] == TRUTHS["seen"] else data.get("truth", "silhouette")
    for truth, name in TRUTHS.items():
        if content == load_manifest(data_root / name).get("content_hash"):
            return truth
    raise ValueError(f"{weights}: trained on data content {content}, none of {list(TRUTHS.values())}")


def fold_piece(fold: int, weights: Path, variant: str = "yolov5s", data_root: Path = Path("data")) -> dict:
    """One fold's detector of `variant` (a key of ROWS) scored and tracked against both truths."""
    out = {
        "fold": fold,
        "variant": variant,
        "weights": str(weights),
        "trained_on": trained_on(weights, data_root),
    }
    out |= {"detection": {}, "tracking": {}}
    for truth, name in TRUTHS.items():
        cfg = compose_config(
            "train", [*detector_cv.VARIANTS[variant][1], f"fold={fold}", f"data.name={name}"]
        )
        out["detection"][truth] = detector_cv.score(cfg, weights, frame_stride=2)
        out["tracking"][truth] = {row: track_row(row, fold, truth, weights) for row in ROWS[variant]}
    return out


def track_row(
    row: str,
    fold: int,
    truth: str,
    weights: Path,
    out: str = "outputs/seen_truth",
    experiment: str = "seen_truth",
    reid: Path | None = None,
    extra: tuple[str, ...] = (),
    folder: str | None = None,
    data: str | None = None,
) -> dict:
    """Fold `fold` tracked against `truth` with Table 4's row `row` (its detector rows on `weights`), with
    the re-ID model `reid` (None: fold 3's shipped one) and the `extra` overrides after the row's own; its
    files go to `<out>/<truth>/<folder>/fold<k>` (folder default: the row, `<row>_own_reid` with another
    re-ID), its MLflow run to `experiment`. `data` names another dataset of the same sequences to track
    and score on than `truth`'s (its files then go to `<out>/<data>/...`)."""
    detector = [] if row.startswith("gt_") else [f"detector.weights={weights}"]
    folder = folder or (row if reid is None else f"{row}_own_reid")
    overrides = (
        _table4_rows()[row][1]
        + list(extra)
        + detector
        + [
            f"reid.weights={reid or 'weights/reid_fold3.pt'}",
            f"fold={fold}",
            f"data.name={data or TRUTHS[truth]}",
            f"output_dir={out}/{data or truth}/{folder}/fold{fold}",
            "video=false",
            "progress=false",
            f"logger.experiment={experiment}",
        ]
    )
    start = time.time()
    metrics = track.run(compose_config("track", overrides))
    return {
        "metrics": {k: metrics[k] for k in TRACK_METRICS if k in metrics},
        "command": "python -m spacetrack.track " + " ".join(overrides),
        "seconds": round(time.time() - start, 1),
    }


def add_rows(piece: dict, rows: list[str], weights: Path, reid_dir: Path | None = None) -> dict:
    """`piece` with Table 4's `rows` tracked as well, against the truth its detector was trained on (each
    a row of the piece's detector variant, or of ground-truth boxes); rows it already holds are kept.
    With `reid_dir` each row is tracked with the fold's own re-ID model (`<reid_dir>/fold<k>/reid.pt`,
    as `make train-reid FOLD=k` writes it) instead of fold 3's shipped one, kept as `<row>+own_reid`."""
    prefix = ROWS[_variant(piece)][0].split("_")[0] + "_"  # Table 4's rows on this variant's detections
    table4 = _table4_rows()
    for row in rows:
        if row not in table4 or not row.startswith((prefix, "gt_")):
            raise ValueError(
                f"--add-rows {row}: not a Table 4 row of {_variant(piece)} detections or of ground-truth "
                f"boxes (rows starting {prefix!r} or 'gt_', experiments/table4_mota/run.py)"
            )
    truth = piece["trained_on"]
    reid = None if reid_dir is None else Path(reid_dir) / f"fold{piece['fold']}" / "reid.pt"
    if reid is not None and not reid.is_file():
        raise ValueError(
            f"{reid} is missing: train fold {piece['fold']}'s re-ID model first "
            f'(make train-reid FOLD={piece["fold"]} ARGS="data.name={TRUTHS[truth]}")'
        )
    for row in rows:
        key = row if reid is None else row + OWN_REID
        if key not in piece["tracking"][truth]:
            piece["tracking"][truth][key] = track_row(row, piece["fold"], truth, weights, reid=reid)
    return piece


def write_table() -> Path:
    found = [json.loads(p.read_text()) for p in sorted((HERE / "results").glob("*_fold*.json"))]
    labels = json.loads((HERE / "labels.json").read_text())
    lines = [
        "# Silhouette truth against seen truth",
        "",
        "Generated by `experiments/seen_truth/run.py`; see README.md.",
        "",
        "## Labels: silhouette boxes the seen truth hides or shrinks below IoU 0.5 (moving targets, every frame)",
        "",
        "| scenario | boxes | hidden | shrunk | lost share |",
        "|---|---|---|---|---|",
    ]
    for name, v in sorted(labels["scenarios"].items(), key=lambda kv: (kv[0] == "all", kv[0])):
        lines.append(f"| {name} | {v['boxes']} | {v['hidden']} | {v['shrunk']} | {v['lost_share']:.3f} |")
    plain = [p for p in found if _variant(p) == "yolov5s"]
    lines += _own_truth_section(plain)
    seen = {v: [p for p in found if p["trained_on"] == "seen" and _variant(p) == v] for v in ROWS}
    for variant in ROWS:
        lines += _seen_section(seen[variant], variant, seen["yolov5s"])
    lines += _ordering_section([p for v in ROWS for p in seen[v]])
    lines += _own_reid_section([p for v in ROWS for p in seen[v]])
    for trained in TRUTHS:
        pieces = [p for p in plain if p["trained_on"] == trained]
        if pieces:
            lines += _sections(trained, pieces)
    path = HERE / "results.md"
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def _triple(d: dict) -> str:
    """mAP@0.5 / mAP@0.5:0.95 / recall at score >= 0.5 of one scored group."""
    return f"{d['map50']:.3f} / {d['map50_95']:.3f} / {d['recall_at_score']:.3f}"


def _variant(piece: dict) -> str:
    """The detector variant a piece measured (pieces that do not say are plain YOLOv5s)."""
    return piece.get("variant", "yolov5s")


def _folds(n: int) -> str:
    """'1 fold', '9 folds'."""
    return f"{n} fold" + ("s" if n != 1 else "")


def _mota(piece: dict, truth: str) -> list[float]:
    """MOTA % of each of its variant's ROWS, `piece`'s detector tracked against `truth`."""
    return [100 * piece["tracking"][truth][row]["metrics"]["mota"] for row in ROWS[_variant(piece)]]


def _own_truth_section(found: list[dict]) -> list[str]:
    """Each truth measured with the detector trained on it, on the folds that have both: the decision."""
    by_fold = defaultdict(dict)
    for p in found:
        by_fold[p["fold"]][p["trained_on"]] = p
    folds = sorted(f for f, pieces in by_fold.items() if len(pieces) == len(TRUTHS))
    if not folds:
        return []
    lines = [
        "",
        "## Each truth with the detector trained on it",
        "",
        "mAP@0.5 / mAP@0.5:0.95 / recall at score >= 0.5 / any-class mAP@0.5; MOTA % with the paper's settings",
        "for the detector and for ground-truth boxes, and the gap between them (silhouette -> seen).",
        "",
        "| fold | detection | yolo_deepsort_paper | gt_deepsort_paper | gap |",
        "|---|---|---|---|---|",
    ]
    totals = defaultdict(list)
    for fold in folds:
        cells, mota = [], {}
        for truth in TRUTHS:
            d = by_fold[fold][truth]["detection"][truth]["all"]
            cells.append(f"{_triple(d)} / {d['map50_any']:.3f}")
            mota[truth] = _mota(by_fold[fold][truth], truth)
            totals[truth].append([d["map50"], *mota[truth]])
        moved = [" -> ".join(f"{mota[t][i]:.1f}" for t in TRUTHS) for i in range(len(ROWS["yolov5s"]))]
        gap = " -> ".join(f"{mota[t][1] - mota[t][0]:.1f}" for t in TRUTHS)
        lines.append(f"| {fold} | {' -> '.join(cells)} | {moved[0]} | {moved[1]} | {gap} |")
    mean = {t: np.mean(totals[t], axis=0) for t in TRUTHS}
    lines.append(
        "| mean | mAP@0.5 "
        + " -> ".join(f"{mean[t][0]:.3f}" for t in TRUTHS)
        + " | "
        + " | ".join(" -> ".join(f"{mean[t][i]:.1f}" for t in TRUTHS) for i in (1, 2))
        + " | "
        + " -> ".join(f"{mean[t][2] - mean[t][1]:.1f}" for t in TRUTHS)
        + " |"
    )
    return lines


def _seen_section(pieces: list[dict], variant: str, plain: list[dict]) -> list[str]:
    """The seen truth alone, every fold trained on it: what the project measures against. Another
    variant than plain YOLOv5s is set beside `plain`'s pieces of the same folds, where there are some."""
    if not pieces:
        return []
    name = detector_cv.VARIANTS[variant][0]
    title = "each fold trained on it" + ("" if variant == "yolov5s" else f", YOLOv5s {name}")
    plain_by_fold = {p["fold"]: p for p in plain} if variant != "yolov5s" else {}
    beside = ["plain YOLOv5s: mAP@0.5 / yolo_deepsort_paper"] if plain_by_fold else []
    lines = [
        "",
        f"## The seen truth, {title}",
        "",
        "mAP@0.5 / mAP@0.5:0.95 / recall at score >= 0.5, overall and per scenario (- where the fold has",
        "no such sequence); MOTA % with the paper's settings and with ground-truth boxes, and their gap.",
        "",
        "| fold | all | any class | dim | strong light | "
        + " | ".join([*ROWS[variant], "gap", *beside])
        + " |",
        "|---|---|---|---|---|---|---|---|" + "---|" * len(beside),
    ]
    pieces = sorted(pieces, key=lambda p: p["fold"])
    motas = []
    for piece in pieces:
        detection = piece["detection"]["seen"]
        cells = ["-" if g not in detection else _triple(detection[g]) for g in ("all", "dim", "strong_light")]
        mota = _mota(piece, "seen")
        motas.append(mota)
        other = plain_by_fold.get(piece["fold"])
        paired = [] if not plain_by_fold else ["-"] if other is None else [
            f"{other['detection']['seen']['all']['map50']:.3f} / {_mota(other, 'seen')[0]:.1f}"
        ]  # fmt: skip
        lines.append(
            f"| {piece['fold']} | {cells[0]} | {detection['all']['map50_any']:.3f} | {cells[1]} | {cells[2]} "
            f"| {mota[0]:.1f} | {mota[1]:.1f} | {mota[1] - mota[0]:.1f} |"
            + "".join(f" {c} |" for c in paired)
        )

    def mean(group: str, key: str = "map50") -> str:
        values = [p["detection"]["seen"][group][key] for p in pieces if group in p["detection"]["seen"]]
        return f"{np.mean(values):.3f}" if values else "-"

    mota = np.mean(motas, axis=0)
    paired = [plain_by_fold[p["fold"]] for p in pieces if p["fold"] in plain_by_fold]
    tail = ""
    if plain_by_fold:
        tail = " - |" if not paired else (
            f" {np.mean([p['detection']['seen']['all']['map50'] for p in paired]):.3f} / "
            f"{np.mean([_mota(p, 'seen')[0] for p in paired]):.1f} ({_folds(len(paired))}) |"
        )  # fmt: skip
    lines.append(
        f"| mean ({_folds(len(pieces))}), mAP@0.5 | {mean('all')} | {mean('all', 'map50_any')} | {mean('dim')} "
        f"| {mean('strong_light')} | {mota[0]:.1f} | {mota[1]:.1f} | {mota[1] - mota[0]:.1f} |" + tail
    )
    return lines


def _ordering_section(pieces: list[dict]) -> list[str]:
    """The paper's ordering on the seen truth: every Table 4 row the folds' pieces hold (those added with
    --add-rows besides each variant's own), MOTA % per fold, on the folds that have each row."""
    by_fold: dict[int, dict[str, float]] = defaultdict(dict)
    for p in pieces:
        for row, result in p["tracking"]["seen"].items():
            if not row.endswith(OWN_REID):  # those have a table of their own (_own_reid_section)
                by_fold[p["fold"]][row] = 100 * result["metrics"]["mota"]
    own = dict.fromkeys(r for rows in ROWS.values() for r in rows)  # detector rows first, then ground truth
    extra = {row for motas in by_fold.values() for row in motas} - own.keys()
    if not extra:
        return []
    own_order = sorted(own, key=lambda r: r.startswith("gt_"))
    order = sorted(extra, key=lambda r: (not r.endswith("_original"), r)) + own_order
    folds = sorted(f for f, motas in by_fold.items() if extra & motas.keys())
    body = [(str(f), [f"{by_fold[f][r]:.1f}" if r in by_fold[f] else "-" for r in order]) for f in folds]
    means = []
    for r in order:
        values = [by_fold[f][r] for f in folds if r in by_fold[f]]
        means.append(f"{np.mean(values):.1f} ({len(values)})" if values else "-")
    intro = [
        "MOTA % of each Table 4 row on the folds that have the added rows (- where a fold lacks the row); the",
        "mean is over the folds that have the row.",
    ]
    return _fold_table(
        "The paper's ordering on the seen truth", intro, order, body + [("mean (folds)", means)]
    )


def _fold_table(
    title: str, intro: list[str], columns: list[str], body: list[tuple[str, list[str]]]
) -> list[str]:
    """A section of results.md: its title, its introduction and a table of `columns` by fold, each row of
    `body` a first cell (a fold, or the mean) and one cell a column."""
    lines = ["", f"## {title}", "", *intro, ""]
    lines += ["| fold | " + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    return lines + [f"| {first} | " + " | ".join(cells) + " |" for first, cells in body]


def _own_reid_section(pieces: list[dict]) -> list[str]:
    """Each row tracked with fold 3's shipped re-ID model against the fold's own (rows added with
    --own-reid), MOTA % per fold, on the folds that have both."""
    pairs: dict[int, dict[str, tuple[float, float]]] = defaultdict(dict)
    for p in pieces:
        rows = p["tracking"]["seen"]
        for key, result in rows.items():
            row = key.removesuffix(OWN_REID)
            if key.endswith(OWN_REID) and row in rows:
                pairs[p["fold"]][row] = (100 * rows[row]["metrics"]["mota"], 100 * result["metrics"]["mota"])
    if not pairs:
        return []
    order = sorted({r for found in pairs.values() for r in found}, key=lambda r: (r.startswith("gt_"), r))
    body = [
        (str(f), [" -> ".join(f"{v:.1f}" for v in pairs[f][r]) if r in pairs[f] else "-" for r in order])
        for f in sorted(pairs)
    ]
    means = []
    for r in order:
        values = np.array([pairs[f][r] for f in pairs if r in pairs[f]])
        means.append(f"{values[:, 0].mean():.1f} -> {values[:, 1].mean():.1f} ({len(values)})")
    intro = [
        "MOTA % with fold 3's shipped re-ID model -> with the fold's own (trained with the fold held out, on",
        "the seen truth: `make train-reid FOLD=k`), on the folds that have both.",
    ]
    return _fold_table("Each fold's own re-ID model", intro, order, body + [("mean (folds)", means)])


def _cell(piece: dict, group: str) -> str:
    a, b = (piece["detection"][t].get(group) for t in TRUTHS)
    if a is None:
        return "-"
    return " -> ".join(_triple(d) for d in (a, b))


def _sections(trained: str, pieces: list[dict]) -> list[str]:
    """The detection and tracking tables of the detectors trained on one truth."""
    lines = [
        "",
        f"## Detectors trained on the {trained} truth",
        "",
        "Detection: mAP@0.5 / mAP@0.5:0.95 / recall at score >= 0.5, scored against the silhouette truth ->",
        "the seen truth; any class: mAP@0.5 with every class as one.",
        "",
        "| fold | all | all, any class | dim | strong light |",
        "|---|---|---|---|---|",
    ]
    for p in pieces:
        a, b = (p["detection"][t]["all"]["map50_any"] for t in TRUTHS)
        lines.append(
            f"| {p['fold']} | {_cell(p, 'all')} | {a:.3f} -> {b:.3f} | {_cell(p, 'dim')} "
            f"| {_cell(p, 'strong_light')} |"
        )
    means = {t: np.mean([p["detection"][t]["all"]["map50"] for p in pieces]) for t in TRUTHS}
    lines += [
        f"| mean mAP@0.5 | {means['silhouette']:.3f} -> {means['seen']:.3f} | | | |",
        "",
        "Tracking: MOTA % with Table 4's row settings, silhouette -> seen truth.",
        "",
        "| fold | " + " | ".join(ROWS["yolov5s"]) + " |",
        "|---|" + "---|" * len(ROWS["yolov5s"]),
    ]
    motas = {t: np.array([_mota(p, t) for p in pieces]) for t in TRUTHS}
    for i, p in enumerate(pieces):
        cells = [" -> ".join(f"{motas[t][i, r]:.1f}" for t in TRUTHS) for r in range(len(ROWS["yolov5s"]))]
        lines.append(f"| {p['fold']} | " + " | ".join(cells) + " |")
    cells = [" -> ".join(f"{motas[t][:, r].mean():.1f}" for t in TRUTHS) for r in range(len(ROWS["yolov5s"]))]
    return lines + ["| mean | " + " | ".join(cells) + " |"]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--folds", type=int, nargs="+", default=[3])
    parser.add_argument("--detectors", type=Path, default=Path("outputs/detector_cv/longer_pretraining"),
                        help="folder holding <variant>_fold<k>/weights/best.pt")  # fmt: skip
    parser.add_argument("--variant", default="yolov5s", choices=list(ROWS),
                        help="the detector variant (experiments/detector_cv/run.py's name)")  # fmt: skip
    parser.add_argument("--data-root", type=Path, default=Path("data"))
    parser.add_argument("--add-rows", nargs="+", default=None, metavar="ROW",
                        help="instead of measuring each fold anew, add these Table 4 rows to its existing "
                             "piece, tracked against the truth its detector was trained on (e.g. "
                             "gam_deepsort_original: the paper's ordering)")  # fmt: skip
    parser.add_argument("--own-reid", type=Path, default=None, metavar="DIR",
                        help="with --add-rows: track with each fold's own re-ID model, DIR/fold<k>/reid.pt "
                             "(e.g. outputs/train_reid/space_default_seen), kept as <row>+own_reid")  # fmt: skip
    args = parser.parse_args()
    if args.own_reid is not None and not args.add_rows:
        raise SystemExit("--own-reid goes with --add-rows: it adds rows to pieces already measured")
    for name in TRUTHS.values():
        if not (args.data_root / name / "manifest.json").is_file():
            raise SystemExit(f"{args.data_root / name} is missing: render it first (see this script's help)")
    labels = label_statistics(args.data_root)
    atomic_write_text(HERE / "labels.json", json.dumps(labels, indent=1) + "\n")
    (HERE / "results").mkdir(exist_ok=True)
    for fold in args.folds:
        weights = args.detectors / f"{args.variant}_fold{fold}" / "weights" / "best.pt"
        if not weights.is_file():
            raise SystemExit(
                f"{weights} is missing: train fold {fold} first (experiments/detector_cv/run.py)"
            )
        infix = "" if args.variant == "yolov5s" else f"_{args.variant}"
        if args.add_rows:
            name = f"{trained_on(weights, args.data_root)}{infix}_fold{fold}.json"
            if not (HERE / "results" / name).is_file():
                raise SystemExit(
                    f"{HERE / 'results' / name} is missing: measure fold {fold} first (no --add-rows)"
                )
            piece = json.loads((HERE / "results" / name).read_text())
            if Path(piece["weights"]) != weights:
                raise SystemExit(f"{name} measured {piece['weights']}, not {weights}: pass its --detectors")
            piece = add_rows(piece, args.add_rows, weights, args.own_reid)
        else:
            piece = fold_piece(fold, weights, args.variant, args.data_root)
            name = f"{piece['trained_on']}{infix}_fold{fold}.json"
        atomic_write_text(HERE / "results" / name, json.dumps(piece, indent=1) + "\n")
        print(
            f"fold {fold}:", {t: round(piece["detection"][t]["all"]["map50"], 3) for t in TRUTHS}, flush=True
        )
    print(write_table().read_text())


if __name__ == "__main__":
    main()
