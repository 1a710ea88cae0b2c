"""One fold of detector training from a `conf/train.yaml` config: data, model, resume, MLflow run.

The run folder holds `weights/best.pt`, `weights/last.pt` and `plots/` (PR curve and a grid of
validation predictions of the best epoch); the same go to MLflow with per-epoch losses and metrics.
The training loop itself is `engine.trainer.Trainer`; started by `torchrun --nproc_per_node=N` (or a
SLURM job of N tasks) the N processes train one model with DistributedDataParallel
(`engine.distributed`).
"""

from __future__ import annotations

import math
import time
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import torch
from hydra.core.hydra_config import HydraConfig
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from spacetrack.config import resolved_dict
from spacetrack.data.crops import CropDataset
from spacetrack.data.exposure import FrameExposure
from spacetrack.data.frame_store import FrameStore
from spacetrack.data.layout import check_rendered_truth, load_manifest, split_sequences
from spacetrack.data.yolo_dataset import YoloDataset, build_augmentation, image_source
from spacetrack.device import resolve_device
from spacetrack.engine.checkpoint import peek_checkpoint, resume_choice, unfinished_checkpoint
from spacetrack.engine.distributed import World, broadcast_object, process_group
from spacetrack.engine.loss import YoloLoss
from spacetrack.engine.plots import plot_confusion_matrix, plot_pr_curves, prediction_grid
from spacetrack.engine.precision import autocast_dtype
from spacetrack.engine.pretrained import load_pretrained, resolve_weights
from spacetrack.engine.trainer import Trainer
from spacetrack.io import file_hash
from spacetrack.mlflow_log import log_artifact_file, log_metrics_step, start_run
from spacetrack.models.yolo import count_parameters
from spacetrack.viz.sheet import write_image

REPORTED = ("map50", "map50_95", "precision", "recall", "recall_at_score", "fitness")


def build_datasets(
    cfg: DictConfig, root: Path, train_names: list[str], val_names: list[str], num_classes: int, enhancer
) -> tuple[CropDataset | YoloDataset, YoloDataset]:
    """(training, validation) data of `cfg.train`: native-resolution crops or letterboxed whole frames
    for training; whole frames at `val_image_size` (null: native) for validation. Frames are decoded
    (and enhanced) once into a `FrameStore` when `cache_frames` is on; it holds only the frames the two
    strides read (every gcd(frame_stride, val_frame_stride)-th)."""
    image_dir, enhance_on_the_fly = image_source(root, train_names + val_names, enhancer.name)
    on_the_fly = enhancer if enhance_on_the_fly else None
    store = None
    if cfg.train.cache_frames:
        store = FrameStore(
            root=root,
            image_dir=image_dir,
            enhancer=on_the_fly,
            enhancer_name=enhancer.name,
            frame_stride=math.gcd(int(cfg.train.frame_stride), int(cfg.train.val_frame_stride)),
        )
    common = {"root": root, "num_classes": num_classes, "store": store}
    frames = {**common, "image_dir": image_dir, "enhancer": on_the_fly}
    augment, reexposure = dict(cfg.train.augment), None
    if augment.get("exposure") and enhancer.name != "none":
        # the enhancement adapts to each frame: re-expose the whole unenhanced frame, then enhance it
        raw = FrameStore(root=root, frame_stride=store.frame_stride if store is not None else 1)
        raw.prepare(train_names)
        reexposure = FrameExposure(raw, enhancer, p=augment["exposure"], gain=augment["exposure_gain"])
        augment["exposure"] = 0.0
    training = {
        "sequences": train_names,
        "frame_stride": cfg.train.frame_stride,
        "augment": build_augmentation(**augment),
        "seed": cfg.train.trainer.seed,
        "reexposure": reexposure,
    }
    if cfg.train.input == "crops":
        if store is None:
            raise ValueError("train.input=crops reads decoded frames: set train.cache_frames=true")
        train_set = CropDataset(**common, **training, crop_size=cfg.train.image_size, **cfg.train.crops)
    elif cfg.train.input == "frames":
        train_set = YoloDataset(**frames, **training, image_size=cfg.train.image_size)
    else:
        raise ValueError(f"train.input must be crops or frames, got {cfg.train.input!r}")
    val_set = YoloDataset(
        **frames,
        sequences=val_names,
        image_size=cfg.train.val_image_size,
        frame_stride=cfg.train.val_frame_stride,
    )
    return train_set, val_set


def train_fold(cfg: DictConfig) -> dict:
    """Train on every fold but `cfg.fold`, validate on it: `metrics` (the best epoch's mAP@0.5,
    mAP@0.5:0.95, precision, recall, recall at score 0.5 and fitness), `best` and `last` (checkpoint
    paths), `run_id` (the MLflow run, or None).

    Launched in several processes (torchrun, a SLURM job of several tasks) the processes train one
    model together; rank 0 alone writes the run folder and the MLflow run (the others get run_id None).
    """
    started = time.perf_counter()  # the time budget (train.trainer.max_minutes) counts the preparation too
    with process_group(cfg.train.trainer.device, key="train.trainer.device") as world:
        fold = _prepare_fold(cfg, world)
        plots = fold.out_dir / "plots"
        if world.is_main:
            plots.mkdir(parents=True, exist_ok=True)
        with _fold_run(cfg, fold, world) as active:
            sizes = {
                "parameters": count_parameters(fold.model),
                "train_images": len(fold.train_set),
                "val_images": len(fold.val_set),
            }
            log_metrics_step(sizes, 0)
            result = fold.trainer.fit(
                model=fold.model,
                loss_fn=fold.loss_fn,
                train_set=fold.train_set,
                val_set=fold.val_set,
                out_dir=fold.out_dir,
                resume_from=fold.resume,
                run_settings=fold.run_settings,
                on_epoch_end=partial(_log_epoch, plots, fold.class_names),
                extra_state={"mlflow_run_id": active.info.run_id} if active is not None else None,
                started=started,
            )
            best, summary = _best_epoch(result)
            if world.is_main:
                _log_best(best, summary, result, plots)
    planned, epochs = result["planned_epochs"], int(cfg.train.trainer.epochs)
    cut = f" ({planned} of {epochs} epochs: train.trainer.max_minutes)" if planned < epochs else ""
    print(
        f"fold {cfg.fold}: best epoch {best['epoch']}{cut}: "
        + ", ".join(f"{k} {v:.4f}" for k, v in summary.items())
    )
    run_id = active.info.run_id if active is not None else None
    return {
        "metrics": summary,
        "best": result["best"],
        "last": result["last"],
        "run_id": run_id,
        "planned_epochs": planned,
    }


@dataclass
class _Fold:
    """What one fold's training is made of, the same in every process of a distributed training."""

    model: torch.nn.Module
    loss_fn: YoloLoss
    train_set: CropDataset | YoloDataset
    val_set: YoloDataset
    trainer: Trainer
    run_settings: dict
    resume: str | Path | None
    out_dir: Path
    class_names: list[str]
    tags: dict[str, str]


def _prepare_fold(cfg: DictConfig, world: World) -> _Fold:
    """The fold's data, model (at its start: seeded, pretrained or resumed), trainer and run folder;
    rank 0 chooses the checkpoint to resume and the folder, the other processes follow."""
    root = Path(cfg.data_root) / cfg.data.name
    manifest = load_manifest(root)
    check_rendered_truth(manifest, root, cfg.data.truth)
    train_names, val_names = split_sequences(manifest, cfg.fold)
    class_names = list(manifest["class_names"])
    if cfg.train.threads:
        torch.set_num_threads(int(cfg.train.threads))
    enhancer = instantiate(cfg.enhance)

    model, loss_fn = _model_and_loss(cfg, len(class_names))
    frozen = model.freeze_backbone(cfg.train.freeze)
    if frozen:
        trained = sum(p.numel() for p in model.parameters() if p.requires_grad)
        print(f"fold {cfg.fold}: {', '.join(frozen)} frozen (train.freeze={cfg.train.freeze}); "
              f"{trained:,} of {count_parameters(model):,} parameters train", flush=True)  # fmt: skip
    weights = resolve_weights(cfg.weights, model.arch)
    train_set, val_set = build_datasets(cfg, root, train_names, val_names, len(class_names), enhancer)
    trainer = instantiate(cfg.train.trainer)
    hint = float32_hint(
        _profile(),
        bool(cfg.train.trainer.amp),
        resolve_device(str(cfg.train.trainer.device)),
        gam=model.arch["gam_position"] is not None,
        budget=cfg.train.trainer.get("max_minutes") is not None,
    )
    if hint and world.is_main:
        print(f"fold {cfg.fold}: {hint}", flush=True)
    content = manifest.get("content_hash")
    run_settings = _run_settings(cfg, weights) | {"data_content": content}
    resume = broadcast_object(
        _resume_from(cfg, trainer, model, run_settings) if world.is_main else None, world
    )
    out_dir = broadcast_object(Path(resume).resolve().parents[1] if resume else Path(cfg.output_dir), world)
    if resume is None and weights is not None:
        print(f"fold {cfg.fold}: " + load_pretrained(model, weights, partial=cfg.weights_partial), flush=True)
    elif resume is None:
        print(f"fold {cfg.fold}: training from scratch (weights={cfg.weights})", flush=True)
        if frozen:
            print(f"fold {cfg.fold}: warning: the frozen blocks keep their random initialisation", flush=True)
    gam = model.arch["gam_position"] or "none"
    levels = str(model.detect.num_levels)
    name = ("yolov5s" if gam == "none" else "yolov5s_gam") + ("_p2" if levels == "4" else "")
    tags = {"fold": str(cfg.fold), "model": name, "gam_position": gam, "head_levels": levels,
            "enhance": enhancer.name, "data_content": str(content)}  # fmt: skip
    return _Fold(
        model, loss_fn, train_set, val_set, trainer, run_settings, resume, out_dir, class_names, tags
    )


def _profile() -> str | None:
    """The `train=` profile Hydra composed (None outside a Hydra run)."""
    if not HydraConfig.initialized():
        return None
    return HydraConfig.get().runtime.choices.get("train")


# The profile that fits one fold's fine-tuning in 30 minutes on two cores where steps run in float32, by
# whether the model has GAM: plain YOLOv5s fits with cpu_float32; GAM's attention costs a float32 step a
# third more, so YOLOv5s + GAM needs cpu_float32_gam (experiments/detector_cv/float32_gam/). The default
# profile and the profiles of this table ahead of the model's own take longer there.
FLOAT32_PROFILES = {False: "cpu_float32", True: "cpu_float32_gam"}


def float32_hint(
    profile: str | None, amp: bool, device: torch.device, *, gam: bool = False, budget: bool = True
) -> str | None:
    """A line for a CPU training whose mixed precision falls back to float32 (`autocast_dtype`: no
    native bfloat16) on a profile that takes over 30 minutes a fold there (the default one; for a model
    with GAM also `cpu_float32`): which profile fits the budget, and (with `budget`: a time budget is
    set) that the budget leaves epochs out; None elsewhere."""
    fits = FLOAT32_PROFILES[gam]
    longer = ["default", *FLOAT32_PROFILES.values()]
    if profile not in longer[: longer.index(fits)] or device.type != "cpu" or not amp:
        return None
    if autocast_dtype(device, amp) is not None:
        return None
    model = "YOLOv5s + GAM" if gam else "YOLOv5s"
    minutes = "about an hour" if profile == "default" else "over 30 minutes"
    cut = (
        ", so its time budget (train.trainer.max_minutes) leaves out the epochs that do not fit"
        if budget
        else ""
    )
    return (
        f"this CPU has no native bfloat16, so steps run in float32 at about half the rate and a "
        f"{model} fold would take {minutes} on two cores with train={profile}{cut}; "
        f"train={fits} fits 30 minutes on a CPU as fast as the 2-core EPYC it was timed on "
        f"(docs/training.md; benchmarks/bench_train.py compares)"
    )


def _fold_run(cfg: DictConfig, fold: _Fold, world: World) -> AbstractContextManager:
    """The fold's MLflow run on rank 0 (None on the others). A resumed training continues the run that
    wrote its checkpoint (when this store has it)."""
    if not world.is_main:
        return nullcontext(None)
    earlier_run = peek_checkpoint(fold.resume).get("mlflow_run_id") if fold.resume else None
    return start_run(
        cfg,
        run_name=f"fold{cfg.fold}",
        parent_run_id=cfg.cv_parent_run_id,
        tags=fold.tags,
        continue_run_id=earlier_run,
    )


def _model_and_loss(cfg: DictConfig, num_classes: int) -> tuple[torch.nn.Module, YoloLoss]:
    """The network at its seeded initialisation and its loss."""
    torch.manual_seed(cfg.train.trainer.seed)
    model = instantiate(cfg.model, num_classes=num_classes)
    loss_fn = YoloLoss(
        anchors=model.detect.anchors,
        strides=model.stride,
        num_classes=num_classes,
        image_size=cfg.train.image_size,
        **cfg.train.loss,
    )
    return model, loss_fn


def _run_settings(cfg: DictConfig, weights: Path | None) -> dict:
    """Everything besides the trainer's own keys that changes the result; a resume must not change it.
    (`_prepare_fold` adds the dataset's `content_hash`: a dataset rendered again under its name, with
    other labels or frames, is another training.)"""
    return (
        resolved_dict(OmegaConf.masked_copy(cfg, ["data", "enhance", "model", "fold"]))
        | {k: v for k, v in resolved_dict(cfg.train).items() if k not in ("trainer", "threads")}
        | {"weights": file_hash(weights) if weights else None, "weights_partial": bool(cfg.weights_partial)}
    )


def _resume_from(cfg: DictConfig, trainer, model, run_settings: dict) -> str | Path | None:
    """The checkpoint to go on from: `resume` (a path), the newest unfinished one of the same settings
    under `resume_dirs` (`auto`), or None."""
    resume = resume_choice(cfg.resume)
    if resume == "auto":
        settings = {**trainer.settings, **run_settings}
        resume = unfinished_checkpoint(list(cfg.resume_dirs), arch=model.arch, settings=settings)
        print(
            f"fold {cfg.fold}: " + (f"resuming {resume}" if resume else "nothing to resume, starting afresh")
        )
    return resume


def _log_epoch(
    plots: Path, class_names: list[str], record: dict[str, float], details: dict, is_best: bool
) -> None:
    """Per epoch: its metrics to MLflow and the console; the plots of the best epoch so far."""
    log_metrics_step({k: v for k, v in record.items() if k != "epoch"}, step=int(record["epoch"]))
    print(" ".join(f"{k}={v:.4g}" for k, v in record.items()), flush=True)
    if is_best:
        plot_pr_curves(details["pr_curves"], class_names, plots / "pr_curve.png")
        plot_confusion_matrix(details["confusion"], class_names, plots / "confusion_matrix.png")
        write_image(plots / "val_predictions.png", prediction_grid(details["examples"], class_names))


def _best_epoch(result: dict) -> tuple[dict, dict[str, float]]:
    """The best epoch's record and its `REPORTED` metrics."""
    best = max(result["history"], key=lambda r: r["fitness"])
    return best, {k: float(best.get(k, float("nan"))) for k in REPORTED}  # older epochs lack some


def _log_best(best: dict, summary: dict[str, float], result: dict, plots: Path) -> None:
    """The best epoch's metrics and the epochs trained to MLflow, with the best weights and plots."""
    log_metrics_step(
        {f"best_{k}": v for k, v in summary.items()}
        | {"best_epoch": best["epoch"], "planned_epochs": result["planned_epochs"]},
        step=0,
    )
    log_artifact_file(result["best"], "weights")
    for name in ("pr_curve.png", "confusion_matrix.png", "val_predictions.png"):
        log_artifact_file(plots / name, "plots")
