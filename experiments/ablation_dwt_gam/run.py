"""Ablation of the paper's two detector changes: YOLOv5s, +DWT/HSV input, +GAM, +both, on the same folds.

Each (variant, fold) is one detector training in the MLflow experiment `detector`, the same runs
`make train FOLD=k ARGS="model=... enhance=..."` makes, so Table 4 finds them and a fold already trained
with the same settings is reused instead of trained again. Its best weights are then scored on the fold's
validation sequences per scenario (dim and strong light among them). Each finished piece is written to
`results/<variant>_fold<k>.json` at once and `results.md` is rebuilt from every piece present, so a
killed run loses at most the training it was in (and that one resumes: `resume=<last.pt>`).

    python experiments/ablation_dwt_gam/run.py --folds 3 -- train.threads=1
    python experiments/ablation_dwt_gam/run.py --folds 0 7 --variants yolov5s,gam -- train=full
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import mlflow
import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf, open_dict
from torch.utils.data import DataLoader

from spacetrack.config import CONF_DIR, resolved_dict
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.data.yolo_dataset import YoloDataset, collate, image_source
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.validate import evaluate
from spacetrack.io import atomic_write_text
from spacetrack.mlflow_log import artifact_file, flatten_params, tracking_uri
from spacetrack.train import run

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
# name in the table -> (file name stem, overrides)
VARIANTS = {
    "YOLOv5s": ("yolov5s", ["model=yolov5s", "enhance=none"]),
    "+DWT/HSV": ("dwt_hsv", ["model=yolov5s", "enhance=dwt_hsv"]),
    "+GAM": ("gam", ["model=yolov5s_gam", "enhance=none"]),
    "+DWT/HSV +GAM": ("dwt_hsv_gam", ["model=yolov5s_gam", "enhance=dwt_hsv"]),
}


def per_scenario(cfg, weights: Path) -> dict[str, dict[str, float]]:
    """mAP of `weights` on the validation sequences of `cfg.fold`, grouped by scenario."""
    root = Path(cfg.data_root) / cfg.data.name
    manifest = load_manifest(root)
    _, val_names = split_sequences(manifest, cfg.fold)
    scenario = {s["name"]: s["scenario"] for s in manifest["sequences"]}
    model = load_detector(weights)
    enhancer = instantiate(cfg.enhance)
    out = {}
    for name in sorted({scenario[v] for v in val_names}):
        names = [v for v in val_names if scenario[v] == name]
        image_dir, on_the_fly = image_source(root, names, enhancer.name)
        data = YoloDataset(root=root, sequences=names, num_classes=len(manifest["class_names"]),
                           image_size=cfg.train.image_size, image_dir=image_dir,
                           enhancer=enhancer if on_the_fly else None,
                           frame_stride=cfg.train.val_frame_stride)  # fmt: skip
        loader = DataLoader(data, batch_size=8, collate_fn=collate)
        metrics, _ = evaluate(model, loader, device=model.stride.device, conf_threshold=0.001,
                              iou_threshold=0.6, max_det=300)  # fmt: skip
        out[name] = {"map50": metrics["map50"], "map50_95": metrics["map50_95"]}
    return out


# Parameters that do not change what training learns: a run differing only in them is reused.
NEUTRAL = ("threads", "device", "workers")


def matching_run(cfg) -> tuple[str, dict[str, float], Path] | None:
    """(run id, best_* metrics, local best.pt) of the newest finished `detector` run trained exactly as
    `cfg` would be (same fold, data, enhancement, model and training settings), or None."""
    client = mlflow.MlflowClient(tracking_uri=tracking_uri(cfg.logger.get("tracking_uri")))
    experiment = client.get_experiment_by_name(cfg.logger.experiment)
    if experiment is None:
        return None
    wanted = {
        k: v
        for k, v in flatten_params(resolved_dict(cfg)).items()
        if k.startswith(("data.", "enhance.", "model.", "train.")) and not any(n in k for n in NEUTRAL)
    }
    runs = client.search_runs(
        [experiment.experiment_id],
        f"tags.fold = '{cfg.fold}' and attributes.status = 'FINISHED'",
        order_by=["attributes.start_time DESC"],
    )
    for found in runs:
        params = found.data.params
        if all(params.get(k) == v for k, v in wanted.items()) and "best_map50" in found.data.metrics:
            local = artifact_file(found.info.run_id, "weights/best.pt", tracking_uri=client.tracking_uri)
            metrics = {k[len("best_") :]: v for k, v in found.data.metrics.items() if k.startswith("best_")}
            return found.info.run_id, metrics, local
    return None


def piece(slug: str, variant_overrides: list[str], fold: int, overrides: list[str]) -> dict:
    """Train (or reuse) one variant on one fold and score it per scenario."""
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
        cfg = compose(
            "train",
            overrides=[*variant_overrides, f"fold={fold}",
                       f"out_dir=outputs/ablation_dwt_gam/{slug}_fold{fold}", *overrides],
        )  # fmt: skip
    with open_dict(cfg):
        cfg.cv_parent_run_id = None
    atomic_write_text(HERE / "configs" / f"{slug}_fold{fold}.yaml", OmegaConf.to_yaml(cfg, resolve=True))
    found = matching_run(cfg)
    if found is None:
        run(cfg)
        found = matching_run(cfg)
        if found is None:
            raise RuntimeError(f"the {slug} fold {fold} training finished but its MLflow run is not found")
    run_id, best, weights = found
    return {"run_id": run_id, **best, "scenarios": per_scenario(cfg, weights)}


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--folds", type=int, nargs="+", default=[3])
    parser.add_argument("--variants", default=",".join(v[0] for v in VARIANTS.values()),
                        help="comma-separated: " + ", ".join(v[0] for v in VARIANTS.values()))  # fmt: skip
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for every run (after --)")
    args = parser.parse_args()
    slugs = args.variants.split(",")
    unknown = sorted(set(slugs) - {v[0] for v in VARIANTS.values()})
    if unknown:
        parser.error(f"unknown variants {unknown}")
    (HERE / "configs").mkdir(exist_ok=True)
    RESULTS.mkdir(exist_ok=True)
    for variant, (slug, variant_overrides) in VARIANTS.items():
        for fold in args.folds:
            path = RESULTS / f"{slug}_fold{fold}.json"
            if slug not in slugs or path.is_file():
                continue
            result = {"variant": variant, "fold": fold, "overrides": args.overrides,
                      **piece(slug, variant_overrides, fold, args.overrides)}  # fmt: skip
            atomic_write_text(path, json.dumps(result, indent=2) + "\n")
            write_tables()


def write_tables() -> None:
    """results.json and results.md from every piece in results/."""
    results = [json.loads(p.read_text()) for p in sorted(RESULTS.glob("*.json"))]
    atomic_write_text(HERE / "results.json", json.dumps(results, indent=2) + "\n")
    atomic_write_text(HERE / "results.md", table(results))


def table(results: list[dict]) -> str:
    """Markdown: per variant the mean over folds of mAP@0.5 and mAP@0.5:0.95, overall and per scenario."""
    scenarios = sorted({s for r in results for s in r["scenarios"]})
    header = ["variant", "mAP@0.5", "mAP@0.5:0.95"] + [f"{s} mAP@0.5 / 0.5:0.95" for s in scenarios]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for variant in VARIANTS:
        mine = [r for r in results if r["variant"] == variant]
        if not mine:
            continue
        by_scenario = defaultdict(list)
        for r in mine:
            for s, m in r["scenarios"].items():
                by_scenario[s].append((m["map50"], m["map50_95"]))
        cells = [
            f"{variant} (folds {', '.join(str(r['fold']) for r in mine)})",
            f"{np.mean([r['map50'] for r in mine]):.3f}",
            f"{np.mean([r['map50_95'] for r in mine]):.3f}",
        ]
        for s in scenarios:
            pairs = np.array(by_scenario[s]) if by_scenario[s] else None
            cells.append("-" if pairs is None else f"{pairs[:, 0].mean():.3f} / {pairs[:, 1].mean():.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    overrides = sorted({" ".join(r["overrides"]) or "(none)" for r in results})
    return (
        f"Overrides `{'`, `'.join(overrides)}`; mean over the folds shown of each fold's best epoch (per "
        "scenario: those best weights on that scenario's validation sequences).\n\n" + "\n".join(lines) + "\n"
    )


if __name__ == "__main__":
    main()
