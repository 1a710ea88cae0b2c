"""Ablation of the paper's two detector changes: YOLOv5s, +DWT/HSV input, +GAM, +both, on the same folds.

Each variant trains one model per fold with `spacetrack.train.run` (MLflow experiment
`detector_ablation`), then its best weights are scored on the fold's validation sequences per scenario
(dim and strong light among them). Writes `results.json`, `results.md` and the resolved config of
every run under `configs/` next to this file.

    python experiments/ablation_dwt_gam/run.py --folds 0 7 -- data=smoke train.threads=1
"""

from __future__ import annotations

import argparse
import json
from collections import defaultdict
from pathlib import Path

import numpy as np
from hydra import compose, initialize_config_dir
from hydra.utils import instantiate
from omegaconf import OmegaConf, open_dict
from torch.utils.data import DataLoader

from spacetrack.config import CONF_DIR
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.data.yolo_dataset import YoloDataset, collate, image_source
from spacetrack.engine.checkpoint import load_detector
from spacetrack.engine.validate import evaluate
from spacetrack.io import atomic_write_text
from spacetrack.train import run

HERE = Path(__file__).resolve().parent
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


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--folds", type=int, nargs="+", default=[0, 7])
    parser.add_argument("overrides", nargs="*", help="Hydra overrides for every run (after --)")
    args = parser.parse_args()
    (HERE / "configs").mkdir(exist_ok=True)
    results = []
    for variant, (slug, variant_overrides) in VARIANTS.items():
        for fold in args.folds:
            with initialize_config_dir(config_dir=str(CONF_DIR), version_base=None):
                cfg = compose(
                    "train",
                    overrides=[*variant_overrides, f"fold={fold}", "logger.experiment=detector_ablation",
                               f"out_dir=outputs/ablation_dwt_gam/{slug}_fold{fold}", *args.overrides],
                )  # fmt: skip
            with open_dict(cfg):
                cfg.cv_parent_run_id = None
            atomic_write_text(
                HERE / "configs" / f"{slug}_fold{fold}.yaml", OmegaConf.to_yaml(cfg, resolve=True)
            )
            best = run(cfg)
            scenarios = per_scenario(cfg, Path(cfg.out_dir) / "weights" / "best.pt")
            results.append({"variant": variant, "fold": fold, **best, "scenarios": scenarios})
            atomic_write_text(HERE / "results.json", json.dumps(results, indent=2) + "\n")
    atomic_write_text(HERE / "results.md", table(results, args))


def table(results: list[dict], args: argparse.Namespace) -> str:
    """Markdown: per variant the mean over folds of mAP@0.5 and mAP@0.5:0.95, overall and per scenario."""
    scenarios = sorted({s for r in results for s in r["scenarios"]})
    header = ["variant", "mAP@0.5", "mAP@0.5:0.95"] + [f"{s} mAP@0.5 / 0.5:0.95" for s in scenarios]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for variant in VARIANTS:
        mine = [r for r in results if r["variant"] == variant]
        by_scenario = defaultdict(list)
        for r in mine:
            for s, m in r["scenarios"].items():
                by_scenario[s].append((m["map50"], m["map50_95"]))
        cells = [
            variant,
            f"{np.mean([r['map50'] for r in mine]):.3f}",
            f"{np.mean([r['map50_95'] for r in mine]):.3f}",
        ]
        for s in scenarios:
            pairs = np.array(by_scenario[s]) if by_scenario[s] else None
            cells.append("-" if pairs is None else f"{pairs[:, 0].mean():.3f} / {pairs[:, 1].mean():.3f}")
        lines.append("| " + " | ".join(cells) + " |")
    return (
        f"Folds {args.folds}, overrides `{' '.join(args.overrides) or '(none)'}`; mean over folds of each "
        "fold's best epoch (per scenario: those best weights on that scenario's validation sequences).\n\n"
        + "\n".join(lines)
        + "\n"
    )


if __name__ == "__main__":
    main()
