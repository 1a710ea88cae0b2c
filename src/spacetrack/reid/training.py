"""One re-ID fold end to end: crops of the eight training folds, training, evaluation on fold k's unseen
identities, weights, metrics and the distance plot written to disk and logged to MLflow.

Every epoch leaves `last.pt` (the whole training state) in the fold's folder; `resume=auto` goes on
from it (`resume=PATH` from another one), in the same MLflow run, to the same weights as a training
that was never stopped. Under `torchrun --nproc_per_node=N` the N processes train one network together (`reid.train.fit`).
"""

from __future__ import annotations

import json
import time
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from torch.utils.data import DataLoader

from spacetrack.config import resolved_dict
from spacetrack.data.layout import load_manifest, split_sequences
from spacetrack.engine.checkpoint import differences, resume_choice, save_checkpoint
from spacetrack.engine.distributed import World, broadcast_object, process_device, process_group
from spacetrack.engine.precision import autocast_dtype
from spacetrack.io import atomic_write_text, load_torch_file
from spacetrack.mlflow_log import log_artifact_file, log_metrics_step, start_run
from spacetrack.reid.crops import Cropper
from spacetrack.reid.dataset import CropDataset, CropTable, collect_crops, cut_crops, jitter_augment
from spacetrack.reid.encoder import Encoder
from spacetrack.reid.evaluation import evaluate_features, plot_distances
from spacetrack.reid.loss import CosineSoftmax
from spacetrack.reid.train import fit, shuffled_loader
from spacetrack.reid.weights import save_weights

# Settings that may differ on resume: they change the speed, not the numbers.
RESUME_NEUTRAL = ("threads", "workers")
CHECKPOINT_FORMAT = "spacetrack-reid-train-1"
# train_reid keys newer than some checkpoints, with the value those checkpoints were trained with.
LATER_KEYS = {"sync_bn": False}
# Where the keys of checkpoints written when train_reid was one flat block went.
FLAT_KEYS = {
    **{k: ("crops", k) for k in ("min_visibility", "min_box_size", "include_static", "frame_stride")},
    **{k: ("fit", k) for k in ("epochs", "lr", "weight_decay", "warmup_epochs", "sync_bn")},
    "eval_frame_stride": ("evaluation", "frame_stride"),
    "eval_batch_size": ("evaluation", "batch_size"),
    "exclude_frames": ("evaluation", "exclude_frames"),
    "gallery_window": ("evaluation", "window"),
    "thresholds": ("evaluation", "thresholds"),
}


def training_settings(cfg: DictConfig, fold: int) -> dict:
    """What a resumed training must share with the one that wrote the checkpoint."""
    train = {k: v for k, v in resolved_dict(cfg.train_reid).items() if k not in RESUME_NEUTRAL}
    data = resolved_dict(OmegaConf.masked_copy(cfg, ["data", "model"]))
    return {"fold": fold, "image_dir": cfg.image_dir, **data, "train_reid": train}


def load_resume_state(path: Path, settings: dict) -> dict:
    """The training state at `path`; refused when it is not one or was made with other settings."""
    state = load_torch_file(path, "re-ID training checkpoint")
    if not isinstance(state, dict) or state.get("format") != CHECKPOINT_FORMAT:
        raise ValueError(f"{path} is not a re-ID training checkpoint (expected format {CHECKPOINT_FORMAT!r})")
    found = {**state["settings"], "train_reid": _nested(state["settings"]["train_reid"])}
    changed = differences(found, settings)
    if changed:
        raise ValueError(f"cannot resume {path} with other settings: {changed}")
    return state


def _nested(train: dict) -> dict:
    """Settings of a checkpoint in the blocks of `conf/train_reid/default.yaml` (older ones are flat)."""
    if "fit" in train:
        return train
    nested: dict = {}
    for key, value in {**LATER_KEYS, **train}.items():
        block, name = FLAT_KEYS.get(key, (None, key))
        (nested.setdefault(block, {}) if block else nested)[name] = value
    return nested


def train_fold(cfg: DictConfig, fold: int, *, parent_run_id: str | None = None) -> dict[str, float]:
    """Train on every fold but `fold`, evaluate on `fold`; returns the held-out metrics (see evaluation).

    Launched in several processes (torchrun, a SLURM job of several tasks) they train one network;
    rank 0 alone evaluates, writes the fold's folder and the MLflow run; every process returns its metrics.
    """
    t = cfg.train_reid
    with process_group(t.device, key="train_reid.device") as world:
        out = Path(cfg.output_dir) / f"fold{fold}"
        if world.is_main:
            out.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(t.seed)
        if t.threads:
            torch.set_num_threads(t.threads)
        device = process_device(t.device, world, key="train_reid.device")
        cropper: Cropper = instantiate(cfg.model.crop)
        net = instantiate(cfg.model.net)
        data = _crops(cfg, fold, cropper)
        loader = _loader(data, cropper, t)
        head = CosineSoftmax(feature_dim=net.feature_dim, num_classes=len(data.train_table.names))
        settings = training_settings(cfg, fold)
        checkpoint = out / "last.pt"
        resume_state = _resume_state(cfg, checkpoint, settings, fold)
        with _fold_run(cfg, fold, parent_run_id, resume_state, world) as active:
            run_id = active.info.run_id if active is not None else None

            def save_state(state: dict) -> None:
                extra = {"format": CHECKPOINT_FORMAT, "settings": settings, "mlflow_run_id": run_id}
                save_checkpoint(checkpoint, state | extra)

            log_metrics_step(data.sizes, step=0)
            started = time.perf_counter()
            stats = fit(
                net,
                head,
                loader,
                **t.fit,
                device=device,
                autocast=autocast_dtype(device, t.amp),
                on_epoch=partial(_log_epoch, fold, t.fit.epochs),
                save_state=save_state,
                resume_state=resume_state,
            )
            train_seconds = time.perf_counter() - started
            trained, train_stats = (net, cropper, device), {**stats, "train_seconds": train_seconds}
            metrics = _finish(cfg, fold, trained, data, out, train_stats) if world.is_main else None
        return broadcast_object(metrics, world)


def _fold_run(
    cfg: DictConfig, fold: int, parent_run_id: str | None, resume_state: dict | None, world: World
) -> AbstractContextManager:
    """The fold's MLflow run on rank 0 (None on the others), the one of the resumed checkpoint when
    there is one."""
    if not world.is_main:
        return nullcontext(None)
    return start_run(
        cfg,
        run_name=f"fold{fold}",
        parent_run_id=parent_run_id,
        tags={"fold": str(fold), "data_content": str(load_manifest(Path(cfg.dataset)).get("content_hash"))},
        continue_run_id=resume_state and resume_state.get("mlflow_run_id"),
    )


def _finish(
    cfg: DictConfig,
    fold: int,
    trained: tuple[torch.nn.Module, Cropper, torch.device],
    data: _FoldCrops,
    out: Path,
    train_stats: dict[str, float],
) -> dict[str, float]:
    """After training the (network, cropper, device) of `trained`: its weights, the held-out evaluation
    and its files in `out` and in MLflow; the metrics with the data sizes and `train_stats`."""
    net, cropper, device = trained
    weights = out / "reid.pt"
    save_weights(weights, net.cpu(), net_kwargs=_kwargs(cfg.model.net), crop_kwargs=_kwargs(cfg.model.crop))
    encoder = Encoder(net, cropper, device=device, batch_size=cfg.train_reid.evaluation.batch_size)
    metrics = _evaluate(cfg, fold, encoder, data, out)
    metrics |= {**data.sizes, **train_stats}
    log_metrics_step(metrics, step=cfg.train_reid.fit.epochs)
    atomic_write_text(out / "metrics.json", json.dumps(metrics, indent=2) + "\n")
    for path in (out / "distances.png", out / "metrics.json", out / "distances.npz"):
        log_artifact_file(path)
    log_artifact_file(weights, "weights")
    return metrics


def _log_epoch(fold: int, epochs: int, epoch: int, stats: dict[str, float]) -> None:
    log_metrics_step(stats, step=epoch)
    print(f"fold {fold} epoch {epoch + 1}/{epochs}: " + ", ".join(f"{k}={v:.4g}" for k, v in stats.items()))


@dataclass
class _FoldCrops:
    """The crops of one fold: training crops of the other folds' identities, held-out ones of `fold`'s."""

    train_table: CropTable
    val_table: CropTable
    train_crops: np.ndarray
    val_crops: np.ndarray
    sizes: dict[str, float]


def _crops(cfg: DictConfig, fold: int, cropper: Cropper) -> _FoldCrops:
    t, root = cfg.train_reid, Path(cfg.dataset)
    train_seqs, val_seqs = split_sequences(load_manifest(root), fold)
    train_table = collect_crops(root, train_seqs, **t.crops)
    # Evaluation asks about what the tracker tracks: moving targets only.
    held_out = {**t.crops, "include_static": False, "frame_stride": t.evaluation.frame_stride}
    val_table = collect_crops(root, val_seqs, **held_out)
    started = time.perf_counter()
    train_crops = cut_crops(root, train_table, cropper, scale=t.context, image_dir=cfg.image_dir)
    val_crops = cut_crops(root, val_table, cropper, image_dir=cfg.image_dir)
    sizes = {
        "train_identities": len(train_table.names),
        "train_crops": len(train_table),
        "val_identities": len(val_table.names),
        "val_crops": len(val_table),
        "crop_seconds": time.perf_counter() - started,
    }
    return _FoldCrops(train_table, val_table, train_crops, val_crops, sizes)


def _loader(data: _FoldCrops, cropper: Cropper, t: DictConfig) -> DataLoader:
    """Shuffled, augmented batches of the training crops (this process's shares of them); the order
    comes from the loader's own seeded generator, so that a resumed training draws the same batches."""
    augment = jitter_augment(height=cropper.height, width=cropper.width, **t.augment)
    dataset = CropDataset(
        data.train_crops,
        data.train_table.identity,
        height=cropper.height,
        width=cropper.width,
        augment=augment,
        seed=t.seed,
    )
    return shuffled_loader(dataset, batch_size=t.batch_size, seed=t.seed, workers=t.workers)


def _resume_state(cfg: DictConfig, checkpoint: Path, settings: dict, fold: int) -> dict | None:
    """The state to go on from, as `resume` says: null, start afresh; auto, the fold's own `checkpoint`
    when there is one; a path, that last.pt (None: start afresh)."""
    resume = resume_choice(cfg.resume)
    if resume is None:
        return None
    if resume != "auto":
        checkpoint = resume
    elif not checkpoint.is_file():
        print(f"fold {fold}: no {checkpoint} to resume, starting afresh")
        return None
    state = load_resume_state(checkpoint, settings)
    print(f"fold {fold}: resuming {checkpoint} after epoch {state['epoch'] + 1}/{cfg.train_reid.fit.epochs}")
    return state


def _evaluate(cfg: DictConfig, fold: int, encoder: Encoder, data: _FoldCrops, out: Path) -> dict[str, float]:
    """Held-out metrics of the encoder on `fold`'s crops; the distance plot and arrays go to `out`."""
    t = cfg.train_reid.evaluation
    crops = torch.from_numpy(data.val_crops).permute(0, 3, 1, 2).float().div(255.0)
    metrics, arrays = evaluate_features(
        encoder.encode_crops(crops),
        data.val_table.identity,
        data.val_table.sequence,
        data.val_table.frame,
        exclude_frames=t.exclude_frames,
        window=t.window,
        thresholds=list(t.thresholds),
    )
    title = f"{Path(cfg.dataset).name}: held-out fold {fold}"
    plot_distances(arrays, list(t.thresholds), out / "distances.png", title=title)
    np.savez_compressed(out / "distances.npz", **arrays)
    return metrics


def _kwargs(node: DictConfig) -> dict:
    """Constructor keywords of a `_target_` config node."""
    return {k: v for k, v in OmegaConf.to_container(node, resolve=True).items() if k != "_target_"}
