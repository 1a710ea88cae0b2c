"""From a `conf/track.yaml` config to the pipeline's parts: weights, cache key, detection stream.

Weights are resolved (and hashed) before any network is loaded, so a run whose sequences are all cached
never loads one.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig

from spacetrack.config import resolved_dict
from spacetrack.device import resolve_device
from spacetrack.io import file_hash, files_hash
from spacetrack.motion.dynamic import DynamicFilter
from spacetrack.onnx_backend import DETECTOR_BACKENDS, check_backend
from spacetrack.pipeline.cache import CacheKey, config_hash
from spacetrack.pipeline.detector import GroundTruthDetector
from spacetrack.pipeline.runner import filter_mode
from spacetrack.pipeline.sources import FrameSource
from spacetrack.pipeline.stages import DetectionStream
from spacetrack.pipeline.timing import StageTimer
from spacetrack.pipeline.weights import fold_artifact

NO_REID = "none"
# Detector keys that change how fast detections come, never what they are: left out of the cache key.
# The weights enter it by file hash instead of path. The backend stays in: ONNX Runtime's outputs differ
# from torch's by float32 rounding, which can break an NMS near-tie the other way.
SPEED_ONLY_KEYS = ("weights", "device", "threads", "onnx_dir")


@dataclass(frozen=True)
class Weights:
    """Resolved weights files: the detector's (None for a detector without weights) and the re-ID
    network's (None: no appearance features)."""

    detector: Path | None
    reid: Path | None


def _needs_detector_weights(cfg: DictConfig) -> bool:
    return "weights" in cfg.detector


def _model_overrides(tags: dict[str, str]) -> list[str]:
    """spacetrack.train overrides that make a detector run with these `gam_position` and `enhance` tags."""
    out = []
    if tags["gam_position"] == "after_sppf":
        out.append("model=yolov5s_gam")
    elif tags["gam_position"] != "none":
        out += ["model=yolov5s_gam", f"model.gam_position={tags['gam_position']}"]
    if tags["enhance"] != "none":
        out.append(f"enhance={tags['enhance']}")
    if tags["head_levels"] == "4":
        out.append("model=yolov5s_p2" if tags["gam_position"] == "none" else "model.p2=true")
    return out


def resolve_weights(cfg: DictConfig) -> Weights:
    """Paths from the config, or the fold's newest training runs in MLflow when a path is null."""
    dataset = Path(cfg.dataset).name
    detector = None
    if _needs_detector_weights(cfg):
        detector = cfg.detector.weights
        if detector is None:
            _require_fold(cfg, "detector.weights")
            tags = {
                "gam_position": str(cfg.detector_run.gam_position),
                "enhance": str(instantiate(cfg.enhance).name),
                "head_levels": "4" if cfg.detector_run.get("p2") else "3",
            }
            detector = fold_artifact(
                experiment=cfg.detector_run.experiment,
                fold=cfg.fold,
                dataset=dataset,
                artifact="weights/best.pt",
                train=("spacetrack.train", [f"fold={cfg.fold}", *_model_overrides(tags)]),
                tags=tags,
                tag_defaults={"head_levels": "3"},
                tracking_uri=cfg.logger.tracking_uri,
            )
    reid = cfg.reid.weights
    if reid is None:
        _require_fold(cfg, "reid.weights")
        reid = fold_artifact(
            experiment=cfg.reid_run.experiment,
            fold=cfg.fold,
            dataset=dataset,
            artifact="weights/reid.pt",
            train=("spacetrack.train_reid", [f"fold={cfg.fold}"]),
            tracking_uri=cfg.logger.tracking_uri,
        )
    for what, path in (("detector", detector), ("re-ID", None if reid == NO_REID else reid)):
        if path is not None and not Path(path).is_file():
            raise FileNotFoundError(f"{what} weights {path} not found")
    return Weights(Path(detector) if detector is not None else None, None if reid == NO_REID else Path(reid))


def _require_fold(cfg: DictConfig, key: str) -> None:
    if cfg.fold is None:
        raise ValueError(
            f"{key} is null, which means the fold's trained weights from MLflow, but no fold is given: "
            f"set fold=k or {key}=PATH"
        )


def ground_truth_root(cfg: DictConfig) -> Path | None:
    """The dataset folder the ground-truth detector reads its boxes from (its `root`, or by default the
    dataset being tracked, or the folder above a sequence given as `source`); None for any other detector."""
    if "root" not in cfg.detector:
        return None
    if cfg.detector.root is not None:
        return Path(str(cfg.detector.root))
    return Path(str(cfg.source)).parent if cfg.source is not None else Path(str(cfg.dataset))


def cache_key(cfg: DictConfig, weights: Weights, source: FrameSource) -> CacheKey:
    """What made (or would make) a source's detections: networks by file hash, settings by config hash,
    the frames by the bytes of the files they come from (a dataset rendered again under the same name is
    another source), and the ground-truth detector's boxes by the bytes of the sequence's truth files."""
    detector = {k: v for k, v in resolved_dict(cfg.detector).items() if k not in SPEED_ONLY_KEYS}
    if "backend" in detector:  # the backend that runs ("auto" resolved on the device)
        device = resolve_device(cfg.detector.device).type
        detector["backend"] = check_backend(detector["backend"], device, DETECTOR_BACKENDS)
        if detector["backend"] == "torch":  # the default: a key without a backend is a torch one
            del detector["backend"]
    detector_id = config_hash(detector)
    if weights.detector is not None:
        detector_id += " " + file_hash(weights.detector)
    truth_root = ground_truth_root(cfg)
    if truth_root is not None:  # the ground-truth detector's boxes are the truth files' rows
        detector_id += " truth " + files_hash(GroundTruthDetector.truth_files(truth_root, source.name))
    reid = NO_REID
    if weights.reid is not None:
        backend = check_backend(cfg.reid.backend, resolve_device(cfg.reid.device).type)
        reid = file_hash(weights.reid) + ("" if backend == "torch" else f" {backend}")
        if cfg.reid_min_score > 0:
            reid += f" min_score={cfg.reid_min_score}"
    # The fusion's `parallel` only changes how fast the same masks come; the dynamic thresholds apply to
    # the cached blobs.
    motion_settings = {k: v for k, v in resolved_dict(cfg.motion).items() if k != "parallel"}
    return CacheKey(
        detector=detector_id,
        reid=reid,
        enhance=config_hash(resolved_dict(cfg.enhance)),
        motion=config_hash({"motion": motion_settings}),
        source=f"{source.description} ({source.num_frames} frames)"
        + (f" {files_hash(source.files)}" if source.files else ""),
    )


def build_dynamic_filter(cfg: DictConfig) -> DynamicFilter:
    """The per-box blob test (`dynamic`), with the track-level decision's `min_share_of_best` in its mode."""
    if filter_mode(cfg.dynamic_filter) != "track":
        return instantiate(cfg.dynamic)
    return instantiate(cfg.dynamic, min_share_of_best=cfg.dynamic_track.min_share_of_best)


def build_stream(cfg: DictConfig, weights: Weights, timer: StageTimer | None = None) -> DetectionStream:
    """The per-frame stages: loads the networks."""
    extra = {"weights": str(weights.detector)} if weights.detector is not None else {}
    if cfg.detector.get("root", "") is None:  # the ground-truth detector reads the tracked dataset
        extra["root"] = str(ground_truth_root(cfg))
    encoder = None
    if weights.reid is not None:
        encoder = instantiate(cfg.reid, weights=str(weights.reid))
    return DetectionStream(
        enhancer=instantiate(cfg.enhance),
        detector=instantiate(cfg.detector, **extra),
        encoder=encoder,
        motion=instantiate(cfg.motion),
        dynamic_filter=build_dynamic_filter(cfg),
        timer=timer,
        overlap_motion=cfg.overlap_motion,
        overlap_reid=cfg.overlap_reid,
        reid_min_score=cfg.reid_min_score,
    )


class _NoBoxes:
    """A detector that finds nothing: drives a `DetectionStream` of the motion stage alone."""

    def begin(self, source: FrameSource) -> None:
        pass

    def __call__(self, rgb: np.ndarray, frame: int) -> np.ndarray:
        return np.zeros((0, 6))


def build_motion_stream(cfg: DictConfig) -> DetectionStream:
    """The motion stage alone (no enhancement, no network): the blobs of each frame for cached detections."""
    return DetectionStream(
        enhancer=lambda rgb: rgb,
        detector=_NoBoxes(),
        encoder=None,
        motion=instantiate(cfg.motion),
        dynamic_filter=build_dynamic_filter(cfg),
        overlap_motion=False,
    )
