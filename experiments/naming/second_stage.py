"""A second stage that names each detection from its own crop: does a classifier name the detector's
boxes better than the detector's class head does?

On the current labels most of what separates the detectors from the issue's dim and recall targets is
naming: with every class as one they are met. Here, for one fold, a classifier of three classes (the
Table 1 network's trunk on 64x64 crops, a cosine-softmax head) is trained on ground-truth crops of the
fold's training sequences (moving and parked objects, every 2nd frame, with box jitter wide enough to
cover the detector's loose boxes). Then:

1. its accuracy on the held-out fold's ground-truth boxes, per scenario: how well one frame's crop names
   a target when the box is right;
2. the fold's detector (a `run.py` piece, reused from its MLflow run) scored exactly as `run.py` scores
   it, but with every detection renamed by the classifier (`evaluate`'s `rename`), written as a piece of
   `<out>/renamed/` beside the detector's own piece in `<out>/results/`.

    python experiments/detector_cv/run.py --folds 2 --variants yolov5s --out experiments/naming/second_stage \\
        -- data.name=space_default_psf train=cpu_float32 train.threads=2
    python experiments/naming/second_stage.py --fold 2 -- data.name=space_default_psf train=cpu_float32

The overrides after `--` are the piece's own (they find its MLflow run). The classifier's weights are
kept under outputs/naming/second_stage and reused when its settings are the same.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import time
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate

from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.engine.plots import xyxy_to_tlwh
from spacetrack.io import atomic_path, atomic_write_text
from spacetrack.reid.crops import Cropper
from spacetrack.reid.dataset import CropDataset, collect_crops, cut_crops, jitter_augment
from spacetrack.reid.loss import CosineSoftmax
from spacetrack.reid.network import ReidNet
from spacetrack.reid.train import fit, shuffled_loader

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent

# The classifier's settings; a saved classifier is reused only when they are the same.
SETTINGS = {
    "input": 64,  # square crops, `contain`: the whole box, undistorted
    "margin": 0.25,  # the box grown by a quarter of its size on every side: the faint body around a lit end
    "min_size": 12.0,  # boxes thinner than this many pixels are widened to it (tiny targets get context)
    "context": 1.5,  # training crops cut at 1.5x, so jitter keeps real surroundings
    "crops": {"min_visibility": 0.1, "min_box_size": 2.0, "include_static": True, "frame_stride": 2},
    # the detector's boxes of faint targets are often far larger than the truth's: wide scale jitter
    "augment": {"jitter_scale": 0.4, "jitter_shift": 0.1, "brightness": 0.3, "flip": 0.5, "blur": 0.2},
    "fit": {"epochs": 8, "lr": 0.001, "weight_decay": 0.0005, "warmup_epochs": 0.5},
    "batch_size": 64,
    "seed": 0,
}


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def crop_set(root: Path, sequences: list[str], cropper: Cropper, scale: float):
    """(table, uint8 crops, class index per crop) of the ground-truth rows of `sequences`."""
    table = collect_crops(root, sequences, **SETTINGS["crops"])
    return table, cut_crops(root, table, cropper, scale=scale), table.object_class.astype(np.int64)


def build(num_classes: int) -> tuple[ReidNet, CosineSoftmax]:
    size = SETTINGS["input"]
    return ReidNet(input_height=size, input_width=size), CosineSoftmax(
        feature_dim=128, num_classes=num_classes
    )


def train_classifier(
    root: Path,
    fold: int,
    train_names: list[str],
    cropper: Cropper,
    num_classes: int,
    path: Path,
    threads: int,
):
    """The fold's classifier, trained on its training sequences `train_names` or loaded from `path` when it
    was saved with the same settings; returns (net, head, record)."""
    net, head = build(num_classes)
    if path.is_file():
        saved = torch.load(path, map_location="cpu", weights_only=False)
        if saved["settings"] == SETTINGS and saved["fold"] == fold:
            net.load_state_dict(saved["net"])
            head.load_state_dict(saved["head"])
            return net.eval(), head.eval(), saved["record"]
    started = time.perf_counter()
    table, crops, labels = crop_set(root, train_names, cropper, SETTINGS["context"])
    cut = time.perf_counter() - started
    size = SETTINGS["input"]
    dataset = CropDataset(crops, labels, height=size, width=size, seed=SETTINGS["seed"],
                          augment=jitter_augment(height=size, width=size, **SETTINGS["augment"]))  # fmt: skip
    loader = shuffled_loader(dataset, batch_size=SETTINGS["batch_size"], seed=SETTINGS["seed"])
    epochs = []
    started = time.perf_counter()
    fit(net, head, loader, device=torch.device("cpu"), **SETTINGS["fit"],
        on_epoch=lambda e, stats: (epochs.append(stats), print(f"epoch {e + 1}: {stats}", flush=True)))  # fmt: skip
    record = {
        "train_sequences": len(train_names),
        "train_crops": len(table),
        "train_class_counts": np.bincount(labels, minlength=num_classes).tolist(),
        "crop_seconds": round(cut, 1),
        "train_minutes": round((time.perf_counter() - started) / 60, 1),
        "threads": threads,
        "epochs": epochs,
    }
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        torch.save({"settings": SETTINGS, "fold": fold, "net": net.state_dict(), "head": head.state_dict(),
                    "record": record}, tmp)  # fmt: skip
    return net.eval(), head.eval(), record


@torch.no_grad()
def predict(net: ReidNet, head: CosineSoftmax, crops: torch.Tensor, batch: int = 512) -> np.ndarray:
    """Class index of each (N, 3, H, W) crop in [0, 1]."""
    out = [head(net(crops[i : i + batch])).argmax(1) for i in range(0, len(crops), batch)]
    return torch.cat(out).numpy() if out else np.zeros(0, dtype=np.int64)


def truth_accuracy(
    root: Path, val_names: list[str], scenario: dict[str, str], cropper: Cropper, net, head, num_classes: int
) -> dict:
    """The classifier on the held-out ground-truth boxes of `val_names` (moving and parked, every 2nd
    frame): accuracy and confusion (rows true, columns predicted) overall and per scenario (`scenario`:
    each sequence's)."""
    table, crops, labels = crop_set(root, val_names, cropper, 1.0)
    predicted = predict(net, head, torch.from_numpy(crops).permute(0, 3, 1, 2).float().div(255))
    groups = {"all": np.ones(len(labels), dtype=bool)}
    seq_scenario = np.array([scenario[table.sequences[s]] for s in table.sequence])
    groups |= {g: seq_scenario == g for g in sorted(set(seq_scenario))}
    out = {}
    for group, keep in groups.items():
        confusion = np.zeros((num_classes, num_classes), dtype=np.int64)
        np.add.at(confusion, (labels[keep], predicted[keep]), 1)
        out[group] = {"crops": int(keep.sum()), "accuracy": float((labels[keep] == predicted[keep]).mean()),
                      "confusion": confusion.tolist()}  # fmt: skip
    return out


def renamer(net: ReidNet, head: CosineSoftmax, cropper: Cropper):
    """`evaluate`'s `rename`: each detection's class from the classifier on its crop of the image."""

    def rename(image: torch.Tensor, detections: np.ndarray) -> np.ndarray:
        crops = cropper(image.float(), xyxy_to_tlwh(detections[:, :4]))
        return predict(net, head, crops).astype(detections.dtype)

    return rename


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fold", type=int, required=True)
    parser.add_argument("--variant", default="yolov5s")
    parser.add_argument("--out", type=Path, default=HERE / "second_stage")
    parser.add_argument("--frame-stride", type=int, default=2, help="as run.py scores (every 2nd frame)")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("overrides", nargs="*", help="the run.py piece's overrides (after --)")
    args = parser.parse_args()
    cv = _load("detector_cv_run", ROOT / "experiments" / "detector_cv" / "run.py")
    torch.set_num_threads(args.threads)
    cfg = cv.variant_config(args.variant, args.fold, args.overrides, args.out)
    if instantiate(cfg.enhance).name != "none":
        raise SystemExit(f"--variant {args.variant}: the classifier names crops of the frames as rendered, "
                         "so only a detector without input enhancement can be renamed by it")  # fmt: skip
    root = Path(cfg.data_root) / cfg.data.name
    manifest = load_manifest(root)
    class_names = list(manifest["class_names"])
    train_names, val_names = split_sequences(manifest, args.fold)
    scenario = {s["name"]: s["scenario"] for s in manifest["sequences"]}
    size = SETTINGS["input"]
    cropper = Cropper(height=size, width=size, margin=SETTINGS["margin"], min_size=SETTINGS["min_size"])
    path = ROOT / "outputs" / "naming" / "second_stage" / f"classifier_{cfg.data.name}_fold{args.fold}.pt"
    net, head, record = train_classifier(
        root, args.fold, train_names, cropper, len(class_names), path, args.threads
    )
    truth = truth_accuracy(root, val_names, scenario, cropper, net, head, len(class_names))
    print(json.dumps({g: round(v["accuracy"], 3) for g, v in truth.items()}), flush=True)
    summary = {"fold": args.fold, "data": cfg.data.name, "classes": class_names, "settings": SETTINGS,
               "training": record, "truth_boxes": truth}  # fmt: skip
    atomic_write_text(args.out / f"classifier_fold{args.fold}.json", json.dumps(summary, indent=2) + "\n")
    found = cv.matching_run(cfg)
    if found is None:
        raise SystemExit(f"no finished detector run of {args.variant} fold {args.fold} with these overrides "
                         f"to rename: train it with run.py --out {args.out}")  # fmt: skip
    run_id, best, weights = found
    scored = cv.score(cfg, weights, args.frame_stride, rename=renamer(net, head, cropper))
    piece = {"slug": args.variant, "variant": cv.VARIANTS[args.variant][0], "fold": args.fold,
             "overrides": args.overrides, "run_id": run_id, "best_epoch": best.get("epoch"),
             "renamed_by": f"the classifier of classifier_fold{args.fold}.json", **scored}  # fmt: skip
    out = args.out / "renamed"
    (out / "results").mkdir(parents=True, exist_ok=True)
    atomic_write_text(
        out / "results" / f"{args.variant}_fold{args.fold}.json", json.dumps(piece, indent=2) + "\n"
    )
    cv.write_tables(out)
    print(json.dumps({k: round(v, 3) for k, v in scored["all"].items() if isinstance(v, float)}))


if __name__ == "__main__":
    main()
