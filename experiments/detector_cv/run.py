"""Detector cross-validation: each variant trained on eight folds and scored on the ninth, per scenario.

Each (variant, fold) is one detector training in the MLflow experiment `detector`, the same run that
`make train FOLD=k ARGS="model=... enhance=..."` makes, so Table 4 finds it, and a fold already trained
with the same settings on the same dataset content (tag `data_content`) is reused instead of trained
again. Its best weights are then scored on every
frame-stride-th frame of the fold's validation sequences at native resolution: mAP@0.5, mAP@0.5:0.95
and the recall of visible targets at score >= 0.5, overall and per scenario. Each finished piece is
written to `<out>/results/<variant>_fold<k>.json` at once and `results.json` / `results.md` are rebuilt
from every piece present, so a killed run loses at most the training it was in, and that one resumes
(`resume=auto`).

    python experiments/detector_cv/run.py --folds 3                      # plain and improved, fold 3
    python experiments/detector_cv/run.py --folds 0 1 2 3 4 5 6 7 8 -- train.threads=1
    python experiments/detector_cv/run.py --variants yolov5s,dwt_hsv,gam,dwt_hsv_gam --folds 0 3 7 \
        --out experiments/ablation_dwt_gam                               # the DWT/HSV and GAM ablation
    python experiments/detector_cv/run.py --start-only --variants yolov5s --out experiments/detector_cv/start

With `--start-only` nothing is trained: each fold is scored with the weights its training would start
from (`weights`: the shipped pretrained file of the variant's model, or a path), what fine-tuning adds
to. With `--tta` nothing is trained either: each piece already in `<out>/results/` is scored again from
its MLflow run with test-time augmentation (the frame also at 0.83 of its size mirrored and at 0.67, one
NMS over all: YOLOv5's views, `detector.tta` in the pipeline), into `<out>/tta/`.

    python experiments/detector_cv/run.py --tta --folds 4 5 6 7 8 --variants yolov5s --out experiments/detector_cv/psf_truth
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from omegaconf import OmegaConf, open_dict
from torch.utils.data import DataLoader

from spacetrack.cli import shown_path
from spacetrack.config import compose_config, resolved_dict
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.data.yolo_dataset import YoloDataset, collate, image_source
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.inference import TTA_VIEWS
from spacetrack.engine.metrics import CONFUSION_IOU, CONFUSION_MIN_SCORE, detection_metrics
from spacetrack.engine.pretrained import resolve_weights
from spacetrack.engine.validate import evaluate
from spacetrack.io import atomic_write_text, file_hash
from spacetrack.mlflow_log import artifact_file, finished_runs, flatten_params, tracking_uri
from spacetrack.train import fit

HERE = Path(__file__).resolve().parent
# slug -> (name in the tables, overrides)
VARIANTS = {
    "yolov5s": ("YOLOv5s", ["model=yolov5s", "enhance=none"]),
    "dwt_hsv": ("+DWT/HSV", ["model=yolov5s", "enhance=dwt_hsv"]),
    "gam": ("+GAM", ["model=yolov5s_gam", "enhance=none"]),
    "dwt_hsv_gam": ("+DWT/HSV +GAM", ["model=yolov5s_gam", "enhance=dwt_hsv"]),
    "yolov5s_p2": ("YOLOv5s + stride-4 level", ["model=yolov5s_p2", "enhance=none"]),
}
METRICS = ("map50", "map50_95", "recall_at_score")
# The detections a detector is scored on: every box above a low score, YOLOv5's validation NMS.
NMS = {"conf_threshold": 0.001, "iou_threshold": 0.6, "max_det": 300}
# The same with every class as one (a box found by a detection of any class: what the tracker follows),
# named with this suffix; pieces scored before it was added lack them.
ANY = "_any"
# The same from detections of every class an anchor scores above the threshold, not only its best one
# (YOLOv5's way to measure mAP: a box the model is unsure how to name also counts for its second class).
MULTI = "_multi"
# `evaluate`'s matches -> the suffix of the metrics computed from them
KINDS = {"matches": "", "matches_any": ANY, "matches_multi": MULTI}
# Parameters that do not change what training learns: a run differing only in them is reused.
NEUTRAL = ("threads", "device", "workers", "channels_last")
# A piece trains its recipe's every epoch, however long that takes on the machine at hand: the profile's
# time budget (train.trainer.max_minutes) would make what a piece learns depend on the machine's speed.
STUDY_OVERRIDES = ["train.trainer.max_minutes=null"]
# Training keys added after runs were made, at the value that trains as those runs did: a run without the
# key matches that value.
ADDED_LATER = {
    "train.trainer.sync_bn": "False",
    "train.trainer.max_minutes": "None",
    "train.augment.exposure": "0.0",
    "train.augment.exposure_gain": "[0.15, 3.0]",
    "train.crops.small_bias": "0.0",
    "train.freeze": "0",
}


def validation_sets(
    cfg, frame_stride: int, per_sequence: bool = False
) -> tuple[list[str], dict[str, YoloDataset], dict[str, str]]:
    """(class names, {scenario: its validation sequences of `cfg.fold` as one dataset}, {sequence: its
    scenario}), scenarios sorted, every `frame_stride`-th frame, enhanced as `cfg.enhance` says;
    `per_sequence`: one dataset per validation sequence, keyed by its name, instead."""
    root = Path(cfg.data_root) / cfg.data.name
    manifest = load_manifest(root)
    _, val_names = split_sequences(manifest, cfg.fold)
    scenario = {s["name"]: s["scenario"] for s in manifest["sequences"] if s["name"] in val_names}
    enhancer = instantiate(cfg.enhance)
    image_dir, on_the_fly = image_source(root, val_names, enhancer.name)
    store = FrameStore(root=root, image_dir=image_dir, enhancer=enhancer if on_the_fly else None,
                       enhancer_name=enhancer.name)  # fmt: skip
    classes = list(manifest["class_names"])
    if per_sequence:
        groups = {v: [v] for v in val_names}
    else:
        groups = {g: [v for v in val_names if scenario[v] == g] for g in sorted(set(scenario.values()))}
    sets = {
        name: YoloDataset(
            root=root, sequences=members, num_classes=len(classes), store=store, frame_stride=frame_stride
        )
        for name, members in groups.items()
    }
    return classes, sets, scenario


def score(cfg, weights: Path, frame_stride: int, augment: bool = False, rename=None) -> dict:
    """METRICS of `weights` on the validation sequences of `cfg.fold`: overall and per scenario, and the
    confusion matrix over all of them (`evaluate`'s: row true class, column predicted, plus background and
    missed); with `augment`, detected with test-time augmentation; with `rename`, each detection named by
    that second stage (`evaluate`'s)."""
    model = load_detector(weights)
    classes, sets, _ = validation_sets(cfg, frame_stride)
    out, pooled, frames, confusion = {}, {kind: [] for kind in KINDS}, 0, []
    for group, data in sets.items():
        loader = DataLoader(data, batch_size=4, collate_fn=collate)
        _, details = evaluate(model, loader, device=model.stride.device, **NMS, class_agnostic=True,
                              multi_label=True, augment=augment, rename=rename)  # fmt: skip
        for kind in KINDS:
            pooled[kind].append(details[kind])
        out[group] = summary(details) | {"frames": len(data)}
        frames += len(data)
        confusion.append(details["confusion"])
    # "all": the scenarios' matches pooled, one mAP over every frame (not a mean of the scenarios')
    joined = {kind: [np.concatenate(a) for a in zip(*parts, strict=True)] for kind, parts in pooled.items()}
    counts = {"classes": classes, "counts": np.sum(confusion, axis=0).tolist()}
    return {"all": summary(joined) | {"frames": frames}, "confusion": counts} | out


def summary(matches: dict) -> dict[str, float]:
    """METRICS of each kind of matches in `matches` (see `KINDS`), named with the kind's suffix."""
    out = {}
    for kind, suffix in KINDS.items():
        result = detection_metrics(*matches[kind])
        out |= {k + suffix: float(result[k]) for k in METRICS}
    return out


def matching_run(cfg) -> tuple[str, dict[str, float], Path] | None:
    """(run id, best_* metrics, local best.pt) of the newest finished `detector` run trained exactly as
    `cfg` would be (same fold, data, enhancement, model, start weights and training settings, and the same
    dataset content: its `data_content` tag, the manifest's `content_hash`), or None."""
    uri = tracking_uri(cfg.logger.get("tracking_uri"))
    wanted = {
        k: v
        for k, v in flatten_params(resolved_dict(cfg)).items()
        if (k.startswith(("data.", "enhance.", "model.", "train.")) or k in ("weights", "weights_partial"))
        and not any(n in k for n in NEUTRAL)
    }
    runs = finished_runs(cfg.logger.experiment, tags={"fold": str(cfg.fold)}, tracking_uri=uri)
    content = str(load_manifest(Path(cfg.data_root) / cfg.data.name).get("content_hash"))
    for found in runs:
        params = found.data.params
        same = all(params.get(k, ADDED_LATER.get(k)) == v for k, v in wanted.items())
        # the labels and frames it trained on (runs from before the tag cannot tell)
        same = same and found.data.tags.get("data_content", content) == content
        if same and "best_map50" in found.data.metrics:
            local = artifact_file(found.info.run_id, "weights/best.pt", tracking_uri=uri)
            metrics = {k[len("best_") :]: v for k, v in found.data.metrics.items() if k.startswith("best_")}
            return found.info.run_id, metrics, local
    return None


def run_folder(slug: str, fold: int, out: Path = HERE) -> Path:
    """The run folder of one variant and fold: outputs/detector_cv/<slug>_fold<k>, or
    outputs/detector_cv/<out's name>/<slug>_fold<k> for results written elsewhere than here."""
    runs = Path("outputs/detector_cv") / ("" if out.resolve() == HERE else out.name)
    return runs / f"{slug}_fold{fold}"


def variant_config(slug: str, fold: int, overrides: list[str], out: Path = HERE):
    """The `train` config of one variant and fold, trained in its `run_folder`."""
    folder = run_folder(slug, fold, out)
    cfg = compose_config(
        "train",
        [*VARIANTS[slug][1], f"fold={fold}", "resume=auto", f"resume_dirs=[{folder.parent}]",
         f"output_dir={folder}", *STUDY_OVERRIDES, *overrides],
    )  # fmt: skip
    with open_dict(cfg):
        cfg.cv_parent_run_id = None
    return cfg


def recorded_config(cfg) -> str:
    """`cfg` resolved as YAML, but for the MLflow store, which stays as configured: once a run has
    started, MLflow puts the absolute store of this machine in the environment the default reads."""
    recorded = OmegaConf.create(OmegaConf.to_container(cfg, resolve=True))
    recorded.logger.tracking_uri = OmegaConf.to_container(cfg.logger, resolve=False)["tracking_uri"]
    return OmegaConf.to_yaml(recorded)


def start_weights(cfg) -> Path:
    """The file a training of `cfg` starts from (`resolve_weights`, as the training resolves it)."""
    path = resolve_weights(cfg.weights, instantiate(cfg.model, num_classes=1).arch)
    if path is None:
        raise SystemExit(f"--start-only: weights={cfg.weights} names no weights file to score")
    return path


def piece(slug: str, fold: int, overrides: list[str], frame_stride: int, out: Path,
          start_only: bool = False) -> dict:  # fmt: skip
    """Train (or reuse) one variant on one fold and score it; with `start_only` score the weights its
    training would start from instead."""
    cfg = variant_config(slug, fold, overrides, out)
    atomic_write_text(out / "configs" / f"{slug}_fold{fold}.yaml", recorded_config(cfg))
    if start_only:
        start = start_weights(cfg)
        return {"run_id": None, "best_epoch": None, "start_only": True, "start": shown_path(start),
                "start_hash": file_hash(start), **score(cfg, start, frame_stride)}  # fmt: skip
    found = matching_run(cfg)
    if found is None:
        fit(cfg)
        found = matching_run(cfg)
        if found is None:
            raise RuntimeError(f"the {slug} fold {fold} training finished but its MLflow run is not found")
    run_id, best, weights = found
    return {"run_id": run_id, "best_epoch": best.get("epoch"), **score(cfg, weights, frame_stride)}


def rescored(result: dict, frame_stride: int, out: Path, augment: bool = False) -> dict | None:
    """`result` (a piece) scored again from the weights of its own MLflow run (with `augment`, with
    test-time augmentation), or None where this store does not hold that run (trained on another
    machine)."""
    cfg = variant_config(result["slug"], result["fold"], result["overrides"], out)
    extra = {"tta": [list(view) for view in TTA_VIEWS]} if augment else {}
    if result.get("start_only"):
        start = start_weights(cfg)
        if file_hash(start) != result["start_hash"]:
            return None
        return {**result, **extra, **score(cfg, start, frame_stride, augment=augment)}
    found = matching_run(cfg)
    if found is None or found[0] != result["run_id"]:
        return None
    return {**result, **extra, **score(cfg, found[2], frame_stride, augment=augment)}


def write_tables(out: Path) -> None:
    """results.json and results.md from every piece in `out`/results."""
    results = [json.loads(p.read_text()) for p in sorted((out / "results").glob("*.json"))]
    atomic_write_text(out / "results.json", json.dumps(results, indent=2) + "\n")
    atomic_write_text(out / "results.md", table(results))


def cell(values: list[float]) -> str:
    return "-" if not values else f"{np.mean(values):.3f}"


def table(results: list[dict]) -> str:
    """Markdown: per variant and fold the three metrics overall, then the means per scenario."""
    lines = [
        "| variant | fold | mAP@0.5 | mAP@0.5:0.95 | recall (score >= 0.5) | any class: mAP@0.5 / recall "
        "| multi-label: mAP@0.5 / mAP@0.5:0.95 | frames |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in sorted(results, key=lambda r: (list(VARIANTS).index(r["slug"]), r["fold"])):
        a = r["all"]
        agnostic = (f"{a['map50' + ANY]:.3f} / {a['recall_at_score' + ANY]:.3f}"
                    if "map50" + ANY in a else "-")  # fmt: skip
        multi = (f"{a['map50' + MULTI]:.3f} / {a['map50_95' + MULTI]:.3f}"
                 if "map50" + MULTI in a else "-")  # fmt: skip
        lines.append(f"| {VARIANTS[r['slug']][0]} | {r['fold']} | {a['map50']:.3f} | {a['map50_95']:.3f} | "
                     f"{a['recall_at_score']:.3f} | {agnostic} | {multi} | {a['frames']} |")  # fmt: skip
    scenarios = sorted(
        {k for r in results for k in r if isinstance(r[k], dict) and "map50" in r[k]} - {"all"}
    )
    lines += ["", "Mean over the folds shown; per scenario mAP@0.5 / recall at score >= 0.5:", ""]
    header = ["variant", "folds", "mAP@0.5", "mAP@0.5:0.95", "recall"] + scenarios
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for slug, (name, _) in VARIANTS.items():
        mine = [r for r in results if r["slug"] == slug]
        if not mine:
            continue
        row = [name, ",".join(str(r["fold"]) for r in mine)]
        row += [cell([r["all"][m] for r in mine]) for m in METRICS]
        for s in scenarios:
            have = [r[s] for r in mine if s in r]
            row.append(
                "-"
                if not have
                else f"{cell([h['map50'] for h in have])} / {cell([h['recall_at_score'] for h in have])}"
            )
        lines.append("| " + " | ".join(row) + " |")
    lines += confusion_tables(results)
    overrides = sorted({" ".join(r["overrides"]) or "(none)" for r in results})
    start_only = all(r.get("start_only") for r in results)
    scored = "the start's weights, not fine-tuned" if start_only else "each fold's best epoch"
    if all(r.get("tta") for r in results):
        scored += (
            ", detected with test-time augmentation (scale, mirrored: "
            + ", ".join(
                f"{scale} {'mirrored' if mirrored else 'as is'}" for scale, mirrored in results[0]["tta"]
            )
            + ")"
        )
    if all(r.get("renamed_by") for r in results):
        scored += ", each detection renamed by " + " and ".join(sorted({r["renamed_by"] for r in results}))
    return (
        f"Overrides `{'`, `'.join(overrides)}`; {scored}, native 640x480 frames.\n\n"
        + "\n".join(lines)
        + "\n"
    )


def confusion_tables(results: list[dict]) -> list[str]:
    """Markdown: per variant the confusion matrices of its pieces summed (pieces scored before it was
    added have none)."""
    lines = []
    for slug, (name, _) in VARIANTS.items():
        mine = [r for r in results if r["slug"] == slug and "confusion" in r]
        if not mine:
            continue
        classes = mine[0]["confusion"]["classes"]
        counts = np.sum([r["confusion"]["counts"] for r in mine], axis=0)
        folds = ",".join(str(r["fold"]) for r in mine)
        lines += ["", f"{name}, folds {folds}: true class (rows) against predicted (columns), detections "
                  f"scoring >= {CONFUSION_MIN_SCORE} paired with targets at IoU >= {CONFUSION_IOU} whatever "
                  "their class:", "",
                  "| true / predicted | " + " | ".join([*classes, "missed"]) + " |",
                  "|" + "---|" * (len(classes) + 2)]  # fmt: skip
        for label, row in zip([*classes, "background"], counts, strict=True):
            lines.append(f"| {label} | " + " | ".join(str(int(c)) for c in row) + " |")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--folds", type=int, nargs="+", default=list(range(9)))
    parser.add_argument(
        "--variants", default="yolov5s,dwt_hsv_gam", help="comma-separated: " + ", ".join(VARIANTS)
    )
    parser.add_argument(
        "--out", type=Path, default=HERE, help="folder of results/, results.json and results.md"
    )
    parser.add_argument("--frame-stride", type=int, default=2, help="score every n-th validation frame")
    parser.add_argument(
        "--rescore",
        action="store_true",
        help="score pieces already present again from their MLflow run (where this store has it): "
        "adds metrics added since they were scored",
    )
    parser.add_argument(
        "--start-only",
        action="store_true",
        help="train nothing: score each fold with the weights its training would start from",
    )
    parser.add_argument(
        "--tta",
        action="store_true",
        help="train nothing: score each piece already in <out>/results again with test-time augmentation "
        "(YOLOv5's views), into <out>/tta/",
    )
    parser.add_argument(
        "overrides", nargs="*", help="Hydra overrides of the train config for every run (after --)"
    )
    args = parser.parse_args()
    slugs = args.variants.split(",")
    unknown = sorted(set(slugs) - set(VARIANTS))
    if unknown:
        parser.error(f"unknown variants {unknown} (known: {', '.join(VARIANTS)})")
    dest = args.out / "tta" if args.tta else args.out
    for folder in (dest / "results", args.out / "configs"):
        folder.mkdir(parents=True, exist_ok=True)
    for fold in args.folds:
        for slug in slugs:
            path = dest / "results" / f"{slug}_fold{fold}.json"
            trained = args.out / "results" / path.name  # the piece scored again (itself without --tta)
            if path.is_file() and not args.rescore:
                continue
            if args.tta or path.is_file():
                result = rescored(json.loads(trained.read_text()), args.frame_stride, args.out,
                                  augment=args.tta) if trained.is_file() else None  # fmt: skip
                if result is None:
                    print(f"{trained}: not trained here, or its MLflow run (or start file) is not in this "
                          "store; not scored")  # fmt: skip
                    continue
            else:
                result = {"slug": slug, "variant": VARIANTS[slug][0], "fold": fold,
                          "overrides": args.overrides,
                          **piece(slug, fold, args.overrides, args.frame_stride, args.out,
                                  args.start_only)}  # fmt: skip
            atomic_write_text(path, json.dumps(result, indent=2) + "\n")
            write_tables(dest)
            print(
                f"{path}: mAP@0.5 {result['all']['map50']:.3f}, recall {result['all']['recall_at_score']:.3f}"
            )


if __name__ == "__main__":
    main()
