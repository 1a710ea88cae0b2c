"""Track a detector study's fold detectors with Table 4's rows on their detections, seen truth.

A study is a folder `experiments/detector_cv/<study>/` whose folds were trained with
`experiments/detector_cv/run.py --out experiments/detector_cv/<study>` (weights under
`outputs/detector_cv/<study>/<variant>_fold<k>/weights/best.pt`): the `yolo_...` rows track plain
YOLOv5s (`yolov5s`), the `gam_...` rows YOLOv5s + GAM on DWT/HSV (`dwt_hsv_gam`). Each fold's detector
tracks the fold's validation sequences with each row's settings (`experiments/table4_mota/run.py`) and
fold 3's shipped re-ID, exactly as `experiments/seen_truth/run.py` tracks the detectors fine-tuned from
the first pretraining stage, so the two compare row by row. A `gt_...` row tracks the fold's
ground-truth boxes on the same truth (no detector: the study's reference). Each (row, fold) lands in
`<study>/tracking/<row>_fold<k>.json` at once, with its MOTA, HOTA, IDF1, ID switches, false positives,
misses and the exact `python -m spacetrack.track` command.

With `--gates` each fold is tracked instead with the paper's settings (`yolo_deepsort_paper`) and then with
each of the keys where they differ from the original DeepSORT settings set back to the original's value,
one at a time and the two detection gates together: what each of the paper's settings costs or gains on
that fold's detections, in `<study>/tracking/gates_fold<k>.json`.

With `--data NAME` every row tracks and is scored on another dataset of the same sequences (the same
images labelled another way, as `score_on.py` scores detectors on it), into `<study>/on_<NAME>/tracking/`.

With `--set LABEL OVERRIDE...` each row is tracked with those overrides after its own (a setting beyond
Table 4's, such as `detector.score=objectness`), into `<study>/tracking/<row>_<LABEL>_fold<k>.json`.

With `--table` nothing is tracked: the pieces already in `<study>/tracking/` (or `on_<NAME>/tracking/`)
become `tracking.md` beside that folder, one line per tracked name (a row and its `--set` label): MOTA per
fold, and over that name's folds the mean MOTA, HOTA and IDF1, the summed errors, and how far it lies below
the ground-truth boxes (`gt_deepsort_paper`) on those same folds. `--reference STUDY` takes the
ground-truth pieces from another study tracked on the same data where this one has none.

    python experiments/detector_cv/track_study.py --study seen_pretraining --folds 2 3
    python experiments/detector_cv/track_study.py --study wider_pretraining --folds 3 --rows gam_deepsort_paper
    python experiments/detector_cv/track_study.py --study wider_pretraining --folds 2 --gates
    python experiments/detector_cv/track_study.py --study wider_pretraining --folds 3 --rows gam_deepsort_paper \
        --set objectness detector.score=objectness
    python experiments/detector_cv/track_study.py --study psf_truth --data space_default_psf --table \
        --reference finetune_lr
    python experiments/detector_cv/track_study.py --study p2_head --folds 2 --yolo-variant yolov5s_p2 \
        --data space_default_psf
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import re
from pathlib import Path
from statistics import fmean

from omegaconf import OmegaConf

from spacetrack.config import REPO_ROOT
from spacetrack.io import atomic_write_text

HERE = Path(__file__).resolve().parent
ROWS = ("yolo_deepsort_paper", "yolo_deepsort_original")
# A row's detector (its name's first word) -> the variant of experiments/detector_cv/run.py trained for it.
DETECTORS = {"yolo": "yolov5s", "gam": "dwt_hsv_gam"}
# The paper's settings (conf/tracker/deepsort_paper.yaml) set back to the original's, one change a run;
# the original values are read from conf/tracker/deepsort_original.yaml.
_ORIGINAL = OmegaConf.load(REPO_ROOT / "conf/tracker/deepsort_original.yaml")
_GATE_KEYS = (
    (), ("min_confidence",), ("n_init",), ("max_cosine_distance",), ("max_iou_distance",),
    ("nms_max_overlap",), ("min_confidence", "n_init"),
)  # fmt: skip
GATES = {
    (",".join(f"{k}={_ORIGINAL[k]}" for k in keys) or "paper"): tuple(
        f"tracker.{k}={_ORIGINAL[k]}" for k in keys
    )
    for keys in _GATE_KEYS
}


def _script(name: str, path: str):
    """The experiment script at `path` (from the repository root), loaded as module `name`."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _seen_truth_study():
    return _script("seen_truth_run", "experiments/seen_truth/run.py")


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--study", required=True, help="a folder of experiments/detector_cv")
    parser.add_argument("--folds", type=int, nargs="+", help="required unless --table")
    parser.add_argument("--rows", nargs="+", default=list(ROWS), help="Table 4 rows on detector boxes")
    parser.add_argument("--detectors", type=Path, help="default: outputs/detector_cv/<study>")
    parser.add_argument(
        "--yolo-variant",
        default=DETECTORS["yolo"],
        help="the run.py variant the yolo_ rows track (default yolov5s; e.g. yolov5s_p2)",
    )
    parser.add_argument("--gates", action="store_true", help="the paper's settings, one key back at a time")
    parser.add_argument(
        "--set", nargs="+", metavar=("LABEL", "OVERRIDE"), help="a label, then overrides after each row's own"
    )
    parser.add_argument(
        "--data",
        help="track and score on this dataset of the same sequences (labelled another way) instead of the "
        "seen truth's; results go to <study>/on_<data>/tracking/",
    )
    parser.add_argument("--table", action="store_true", help="write tracking.md from the pieces present")
    parser.add_argument("--reference", help="with --table: a study whose ground-truth pieces to compare with")
    args = parser.parse_args()
    folder = HERE / args.study
    if not folder.is_dir():
        raise SystemExit(f"--study {args.study}: {folder} is not a study folder")
    if args.table:
        reference = HERE / args.reference if args.reference else None
        if reference is not None and not reference.is_dir():
            raise SystemExit(f"--reference {args.reference}: {reference} is not a study folder")
        print(write_table(folder, args.data, reference))
        return
    if not args.folds:
        raise SystemExit("--folds: give the folds to track (or --table to tabulate what is tracked)")
    label, extra = (args.set[0], tuple(args.set[1:])) if args.set else ("", ())
    if args.set and (not re.fullmatch(r"[a-z0-9_]+", label) or not extra or not all("=" in e for e in extra)):
        raise SystemExit(
            f"--set {' '.join(args.set)}: give a label of a-z, 0-9 and _, then KEY=VALUE overrides"
        )
    if (args.set or args.data) and args.gates:
        raise SystemExit(
            "--gates tracks the seen truth's dataset with the paper's settings only: no --set or --data"
        )
    rows = ["yolo_deepsort_paper"] if args.gates else args.rows
    for row in rows:
        if row.split("_")[0] not in (*DETECTORS, "gt"):
            raise SystemExit(
                f"--rows {row}: not a Table 4 row on a study's detector boxes (yolo_... or gam_...) "
                "or on ground-truth boxes (gt_...)"
            )
    cv = _script("detector_cv_run", "experiments/detector_cv/run.py")

    slugs = {**DETECTORS, "yolo": args.yolo_variant}  # a row's prefix -> the run.py variant it tracks

    def weights_of(row: str, fold: int) -> Path | None:
        if row.split("_")[0] not in slugs:
            return None  # a gt_ row: ground-truth boxes, no detector
        slug = slugs[row.split("_")[0]]
        run = args.detectors / f"{slug}_fold{fold}" if args.detectors else cv.run_folder(slug, fold, folder)
        weights = run / "weights" / "best.pt"
        if not weights.is_file():
            raise SystemExit(f"{weights} is missing: train fold {fold} first (see README.md)")
        return weights

    # every detector present before anything is tracked
    weights = {(row, fold): weights_of(row, fold) for fold in args.folds for row in rows}
    study = _seen_truth_study()
    out = folder / f"on_{args.data}" / "tracking" if args.data else folder / "tracking"
    out.mkdir(parents=True, exist_ok=True)
    for fold in args.folds:
        if args.gates:
            track_gates(study, args.study, fold, weights[rows[0], fold], out)
            continue
        for row in rows:
            name = f"{row}_{label}" if label else row
            result = study.track_row(
                row, fold, "seen", weights[row, fold], out=f"outputs/{args.study}", experiment=args.study,
                extra=extra, folder=name, data=args.data,
            )  # fmt: skip
            detector = weights[row, fold]
            piece = {"row": row, "fold": fold, "weights": str(detector) if detector else None, **result}
            if extra:
                piece["extra"] = list(extra)
            atomic_write_text(out / f"{name}_fold{fold}.json", json.dumps(piece, indent=1) + "\n")
            print(f"fold {fold} {name}: MOTA {result['metrics']['mota']:.3f}", flush=True)


def track_gates(study, name: str, fold: int, weights: Path, out: Path) -> None:
    """Fold `fold` tracked with the paper's settings and with each `GATES` change, into
    `<out>/gates_fold<k>.json`."""
    rows = {}
    for label, extra in GATES.items():
        result = study.track_row(
            "yolo_deepsort_paper", fold, "seen", weights, out=f"outputs/{name}", experiment=name,
            extra=extra, folder="gates/" + re.sub(r"[^a-z0-9_.]+", "_", label),
        )  # fmt: skip
        rows[label] = result
        print(f"fold {fold} paper settings, {label}: MOTA {result['metrics']['mota']:.3f}", flush=True)
    piece = {"row": "yolo_deepsort_paper", "fold": fold, "weights": str(weights), "gates": rows}
    atomic_write_text(out / f"gates_fold{fold}.json", json.dumps(piece, indent=1) + "\n")


GT_ROW = "gt_deepsort_paper"


def _pieces(folder: Path, name: str = "*") -> dict[str, dict[int, dict]]:
    """Tracked name -> fold -> piece, for every `<name>_fold<k>.json` in `folder` (gates pieces aside;
    `name`: that tracked name only)."""
    found: dict[str, dict[int, dict]] = {}
    for path in sorted(folder.glob(f"{name}_fold*.json")):
        match = re.fullmatch(r"(.+)_fold(\d+)\.json", path.name)
        if match is None or match[1] == "gates":
            continue
        try:
            piece = json.loads(path.read_text())
            float(piece["metrics"]["mota"])
        except (ValueError, KeyError, TypeError) as err:
            raise SystemExit(f"{path}: not a tracking piece ({err!r})") from err
        found.setdefault(match[1], {})[int(match[2])] = piece
    return found


def write_table(folder: Path, data: str | None = None, reference: Path | None = None) -> Path:
    """`tracking.md` beside `<folder>[/on_<data>]/tracking/`: each tracked name's MOTA per fold and, over its
    folds, mean MOTA / HOTA / IDF1, summed IDSW / FP / FN and the gap to ground-truth boxes on those folds."""
    sub = Path(f"on_{data}") if data else Path()
    tracking = folder / sub / "tracking"
    names = _pieces(tracking) if tracking.is_dir() else {}
    if not names:
        raise SystemExit(f"{tracking}: no tracking pieces to tabulate: track some folds first")
    gt, gt_from = names.get(GT_ROW), tracking
    if gt is None and reference is not None:
        gt_from = reference / sub / "tracking"
        gt = _pieces(gt_from, GT_ROW).get(GT_ROW) if gt_from.is_dir() else None
        if gt:
            names = {GT_ROW: gt, **names}
    folds = sorted({f for by_fold in names.values() for f in by_fold})

    def pct(value) -> str:
        return f"{100 * value:.1f}"

    lines = [
        f"MOTA (%) per fold of each tracked name in `{(folder.name / sub / 'tracking').as_posix()}/` "
        "(a Table 4 row, then its `--set` label); over the folds it has: the mean, how far below "
        f"ground-truth boxes (`{GT_ROW}`"
        + (f", from `{gt_from.relative_to(HERE).as_posix()}/`" if gt and gt_from != tracking else "")
        + ") it lies on those same folds, HOTA and IDF1 (%), and the summed errors. Written by "
        "`track_study.py --table` from the pieces present.",
        "",
        "| tracked as | " + " | ".join(str(f) for f in folds) + " | folds | mean | below gt | HOTA | IDF1 | "
        "IDSW / FP / FN |",
        "|---" * (len(folds) + 7) + "|",
    ]
    for name in sorted(names, key=lambda n: (n != GT_ROW, n)):
        by_fold = names[name]
        got = [by_fold[f]["metrics"] for f in sorted(by_fold)]
        cells = [pct(by_fold[f]["metrics"]["mota"]) if f in by_fold else "-" for f in folds]
        gap = ""
        if gt and name != GT_ROW and set(by_fold) <= set(gt):
            gap = f"{100 * (fmean(gt[f]['metrics']['mota'] for f in by_fold) - fmean(m['mota'] for m in got)):.1f}"
        extra = [fmean(m[k] for m in got) if all(k in m for m in got) else None for k in ("hota", "idf1")]
        errors = " / ".join(
            str(int(sum(m[k] for m in got))) if all(k in m for m in got) else "-"
            for k in ("idsw", "fp", "fn")
        )
        lines.append(
            f"| `{name}` | "
            + " | ".join(cells)
            + f" | {len(got)} | {pct(fmean(m['mota'] for m in got))} | {gap} | "
            + " | ".join(pct(v) if v is not None else "-" for v in extra)
            + f" | {errors} |"
        )
    settings = {
        name[len(row) + 1 :]: piece["extra"]
        for name, by_fold in names.items()
        for piece in by_fold.values()
        if piece.get("extra") and name.startswith((row := piece["row"]) + "_")
    }
    if settings:
        lines += ["", "Each `--set` label's overrides, after the row's own:", ""]
        lines += [f"- `{label}`: `{' '.join(settings[label])}`" for label in sorted(settings)]
    out = folder / sub / "tracking.md"
    atomic_write_text(out, "\n".join(lines) + "\n")
    return out


if __name__ == "__main__":
    main()
