"""Track moving space targets in video: the whole pipeline from frames to MOT results, MP4s and metrics.

python -m spacetrack.track fold=3                       (a fold's sequences with that fold's weights)
python -m spacetrack.track source=clip.mp4 detector.weights=best.pt reid.weights=reid.pt
python -m spacetrack.track -m tracker.max_cosine_distance=0.05,0.1,0.2 fold=3     (a sweep, from the cache)
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.data.layout import load_manifest, read_mot, split_sequences
from spacetrack.evaluation import OVERALL, evaluate
from spacetrack.evaluation.mot import class_accuracy, named_matches
from spacetrack.io import atomic_write_text
from spacetrack.mlflow_log import log_artifact_file, log_metrics_step, start_run
from spacetrack.motion.dynamic import DynamicHold
from spacetrack.pipeline.build import (
    Weights,
    build_dynamic_filter,
    build_motion_stream,
    build_stream,
    cache_key,
    resolve_weights,
)
from spacetrack.pipeline.cache import DetectionCache
from spacetrack.pipeline.runner import (
    SequenceOutput,
    SequenceResult,
    TrackingSetup,
    build_tracker,
    filter_mode,
    run_source,
)
from spacetrack.pipeline.sources import FrameSource, limit, open_source, sequence_source
from spacetrack.pipeline.stages import DetectionStream
from spacetrack.pipeline.timing import StageTimer
from spacetrack.track_detections import rows_as_mot
from spacetrack.tracking.offline import OfflineSettings

log = logging.getLogger(__name__)
SCORES = ("hota", "deta", "assa", "mota", "motp", "idf1", "idsw", "fp", "fn", "mt", "ml", "precision", "recall")  # fmt: skip


def select_sources(cfg: DictConfig) -> list[tuple[FrameSource, Path | None]]:
    """(source, its gt.txt or None) for `source=`, `sequence=` or `fold=`, in that order of precedence."""
    if cfg.source is not None:
        source = open_source(cfg.source, fps=cfg.fps)
        gt = Path(str(cfg.source)) / "gt" / "gt.txt"
        return [(source, gt if gt.is_file() else None)]
    if cfg.sequence is None and cfg.fold is None:
        raise ValueError(
            "nothing to track: give fold=K, sequence=NAME|all or source=PATH|CAMERA_INDEX|realsense"
        )
    root = Path(cfg.dataset)
    manifest = load_manifest(root)
    known = [s["name"] for s in manifest["sequences"]]
    if cfg.sequence == "all":  # every sequence of the dataset (its folds' models saw most of them)
        names = known
    elif cfg.sequence is not None:
        names = [str(cfg.sequence)]
        if names[0] not in known:
            raise ValueError(f"sequence {names[0]!r} is not in {root} (it has {sorted(known)})")
    else:
        names = split_sequences(manifest, cfg.fold)[1]
    fps = {s["name"]: s["fps"] for s in manifest["sequences"]}
    return [(sequence_source(root, n, fps=cfg.fps or fps[n]), root / n / "gt" / "gt.txt") for n in names]


def cache_folder(cfg: DictConfig) -> Path:
    """One cache folder per detector kind, enhancement and re-ID use, so the rows of Table 4 never evict
    each other's detections."""
    kind = str(cfg.detector._target_).rsplit(".", 1)[-1]
    if "weights" in cfg.detector:
        kind += f"-{cfg.detector_run.gam_position}"
    kind += f"-{cfg.enhance._target_.rsplit('.', 1)[-1]}"
    if cfg.reid.weights == "none":
        kind += "-noreid"
    return Path(cfg.cache.dir) / kind


def offline_settings(cfg: DictConfig) -> OfflineSettings | None:
    """`offline` of conf/track.yaml as the post-processing settings, or None when it is off."""
    offline = cfg.get("offline")
    if offline is None or not offline.enabled:
        return None
    return OfflineSettings(
        backfill=bool(offline.backfill), max_gap=offline.max_gap, smooth_frames=offline.smooth_frames
    )


class _LazyStream:
    """The per-frame stages, built (networks loaded) on the first source that is not cached, once."""

    def __init__(self, cfg: DictConfig, weights: Weights) -> None:
        self.cfg, self.weights, self.stream = cfg, weights, None

    def __call__(self) -> DetectionStream:
        if self.stream is None:
            if self.cfg.threads:
                torch.set_num_threads(int(self.cfg.threads))
            self.stream = build_stream(self.cfg, self.weights, StageTimer())
        self.stream.timer = StageTimer()
        return self.stream


def _check_reid(cfg: DictConfig, weights: Weights) -> None:
    if weights.reid is None and cfg.tracker.get("max_cosine_distance") is not None:
        raise ValueError(
            "reid.weights=none gives no appearance features, but the tracker matches by appearance; "
            "use tracker=sort (or tracker.max_cosine_distance=null)"
        )


def _track_source(
    cfg: DictConfig,
    source: FrameSource,
    weights: Weights,
    stream: _LazyStream,
    cache: DetectionCache | None,
    out_dir: Path,
) -> SequenceResult:
    """One source through the pipeline with a fresh tracker."""
    mode = filter_mode(cfg.dynamic_filter)
    setup = TrackingSetup(
        tracker=build_tracker(cfg),
        make_stream=stream,
        make_motion_stream=lambda: build_motion_stream(cfg),
        dynamic_filter=build_dynamic_filter(cfg),
        mode=mode,
        hold=DynamicHold(**cfg.dynamic_hold) if mode == "frame" else None,
        offline=offline_settings(cfg),
    )
    output = SequenceOutput(out_dir=out_dir, video=cfg.video, progress=cfg.progress)
    return run_source(source, setup, output, cache=cache, key=cache_key(cfg, weights, source))


def _sequence_metrics(
    cfg: DictConfig, result: SequenceResult, gt_path: Path | None, pairs: dict, named: dict
) -> dict:
    """Speed, and the scores against `gt_path` when there is one (its (gt, hyp) pair added to `pairs`, its
    matched boxes' classes to `named`: how well the tracks' voted classes name the targets)."""
    metrics = {"fps": result.num_frames / result.wall_seconds, **result.timings}
    if gt_path is None:
        return metrics
    gt = read_mot(gt_path)
    pairs[result.name] = (gt[gt[:, 0] <= result.num_frames], rows_as_mot(result.rows))
    matching: dict = {}
    scores = evaluate(
        {result.name: pairs[result.name]},
        iou_threshold=cfg.iou_threshold,
        min_visibility=cfg.min_visibility,
        accumulators=matching,
    )[result.name]
    metrics |= {k: scores[k] for k in SCORES}
    if result.classes is not None:  # not after offline post-processing, whose boxes no detection named
        named[result.name] = named_matches(
            *pairs[result.name],
            result.classes,
            iou_threshold=cfg.iou_threshold,
            min_visibility=cfg.min_visibility,
            matching=matching[result.name],
        )
        metrics |= class_accuracy(named[result.name])
    return metrics


def _log_sequence(result: SequenceResult, metrics: dict) -> None:
    log_metrics_step({f"{result.name}/{k}": v for k, v in metrics.items()}, step=0)
    log_artifact_file(result.mot_path, "results")
    if result.classes_path is not None and result.classes_path.is_file():
        log_artifact_file(result.classes_path, "results")
    if result.video_path is not None:
        log_artifact_file(result.video_path, "video")
    log.info("%s: %s", result.name, _brief(metrics))


def run(cfg: DictConfig) -> dict[str, float]:
    """Track every selected source; return the overall scores (when there is ground truth) and timings.

    Writes `<output_dir>/<name>.txt` (MOT rows `frame,id,x,y,w,h,1,-1,-1,-1`), `<name>.mp4` (with
    `video`) and `metrics.json`; logs one MLflow run with per-sequence metrics (`<name>/mota`, ...), the
    overall ones and the clips.
    """
    sources = select_sources(cfg)
    weights = resolve_weights(cfg)
    _check_reid(cfg, weights)
    out_dir = Path(cfg.output_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    cache = DetectionCache(cache_folder(cfg), rebuild=cfg.cache.rebuild) if cfg.cache.enabled else None
    stream = _LazyStream(cfg, weights)  # the networks load once, and only if some source is not cached
    run_name = f"fold{cfg.fold}" if cfg.fold is not None and cfg.sequence is None else None
    results: list[SequenceResult] = []
    pairs: dict = {}
    named: dict = {}
    with start_run(cfg, run_name=run_name or sources[0][0].name, parent_run_id=cfg.sweep_parent_run_id):
        for source, gt_path in sources:
            result = _track_source(cfg, limit(source, cfg.max_frames), weights, stream, cache, out_dir)
            results.append(result)
            _log_sequence(result, _sequence_metrics(cfg, result, gt_path, pairs, named))
        metrics = summary(results, pairs, cfg, named)
        log_metrics_step(metrics, step=0)
        atomic_write_text(out_dir / "metrics.json", json.dumps(metrics, indent=2) + "\n")
        log_artifact_file(out_dir / "metrics.json")
    log.info("overall: %s -> %s", _brief(metrics), out_dir)
    return metrics


def summary(
    results: list[SequenceResult], pairs: dict, cfg: DictConfig, named: dict | None = None
) -> dict[str, float]:
    """Overall scores over all sequences with ground truth (the class accuracies over the boxes of all
    sequences in `named`), and frame-weighted per-stage timings."""
    frames = sum(r.num_frames for r in results)
    metrics: dict[str, float] = {
        "num_sequences": float(len(results)),
        "num_frames": float(frames),
        "num_tracks": float(sum(len(set(r.rows[:, 1].astype(int))) for r in results)),
        "cached_sequences": float(sum(r.from_cache for r in results)),
        "fps": frames / sum(r.wall_seconds for r in results),
    }
    stages = sorted({k for r in results for k in r.timings})
    for stage in stages:
        metrics[stage] = sum(r.timings.get(stage, 0.0) * r.num_frames for r in results) / frames
    if pairs:
        overall = evaluate(pairs, iou_threshold=cfg.iou_threshold, min_visibility=cfg.min_visibility)[OVERALL]
        metrics |= {k: overall[k] for k in SCORES}
    if named:
        metrics |= class_accuracy(np.concatenate(list(named.values())))
    return metrics


def _brief(metrics: dict[str, float]) -> str:
    return ", ".join(f"{k} {v:.4g}" for k, v in metrics.items() if "/" not in k)


@cli.entry_point("track", metric="mota", files="output_dir")
def main(cfg: DictConfig) -> float:
    """Returns MOTA (what a sweeper maximises); NaN when the sources have no ground truth."""
    return run(cfg).get("mota", float("nan"))


if __name__ == "__main__":
    main()
