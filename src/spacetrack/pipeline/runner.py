"""One source through the whole pipeline: cached or fresh detections -> tracker -> MOT file, MP4, timings.

Nothing is half-written: the MOT file and the MP4 replace their paths only when the sequence completes,
and the cache is valid only once its sidecar is written after its arrays.
"""

from __future__ import annotations

import json
import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import ExitStack
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig
from tqdm import tqdm

from spacetrack.data.geometry import CLASS_NAMES
from spacetrack.data.layout import BOX, CONF
from spacetrack.io import atomic_write_text
from spacetrack.motion.blobs import Blob, blob_boxes
from spacetrack.motion.dynamic import DynamicFilter, DynamicHold
from spacetrack.pipeline.cache import CachedSequence, CacheKey, DetectionCache
from spacetrack.pipeline.outputs import Annotator
from spacetrack.pipeline.sources import FrameSource
from spacetrack.pipeline.stages import DetectionStream, FrameDetections, dynamic_flags
from spacetrack.pipeline.timing import StageTimer
from spacetrack.tracking import DeepSort
from spacetrack.tracking.class_vote import UNKNOWN
from spacetrack.tracking.io import FEATURES, write_mot_results
from spacetrack.tracking.offline import OfflineSettings, post_process
from spacetrack.viz.video import VideoWriter


@dataclass
class SequenceResult:
    """rows: (N, 6) `frame, id, x, y, w, h` tracker output (tlwh pixels); timings: ms per frame by stage;
    classes: (N, 2) per row the class of the detection its track matched on that frame (-1: none) and the
    track's final voted class (None when offline post-processing changed the rows); classes_path: the
    file with each track's voted class (`write_track_classes`)."""

    name: str
    rows: np.ndarray
    num_frames: int
    from_cache: bool
    wall_seconds: float
    timings: dict[str, float] = field(default_factory=dict)
    mot_path: Path | None = None
    video_path: Path | None = None
    classes: np.ndarray | None = None
    classes_path: Path | None = None


def cached_frames(
    cached: CachedSequence,
    dynamic_filter: DynamicFilter,
    images: Iterable[np.ndarray] | None = None,
    motion: Iterator[FrameDetections] | None = None,
) -> Iterator[FrameDetections]:
    """The per-frame view of cached detections, frames 1..num_frames, flagged dynamic by `dynamic_filter`
    from the cached blobs, with images when given.

    motion: instead of the cached blobs (made by other motion settings), the frames of a stream of the
        motion stage alone, with their images when it keeps them; once every frame is out, their blobs
        are `cached.blobs`.
    """
    if (cached.blobs is None) == (motion is None):
        raise ValueError("cached detections take either their cached blobs or a motion stream")
    rows = cached.rows
    bounds = np.searchsorted(rows[:, 0].astype(int), np.arange(1, cached.num_frames + 2))
    image_iter = iter(images) if images is not None else None
    fresh: list[list[Blob] | None] = []
    for f in range(1, cached.num_frames + 1):
        part = slice(bounds[f - 1], bounds[f])
        if motion is not None:
            item = next(motion, None)
            if item is None:
                raise ValueError(
                    f"the source ended after {f - 1} frames; the cached detections have {cached.num_frames}"
                )
            blobs, image = item.blobs, item.image
            fresh.append(blobs)
        else:
            blobs = cached.blobs[f - 1]
            image = next(image_iter) if image_iter is not None else None
        dynamic = dynamic_flags(dynamic_filter, rows[part], blobs)
        yield FrameDetections(f, rows[part], dynamic, cached.classes[part], image, blobs)
    if motion is not None:
        cached.blobs = fresh


def _reaching_tracker(item: FrameDetections, mode: str, hold: DynamicHold | None) -> np.ndarray:
    """(N,) bool: the frame's detections that the tracker sees in filter `mode`."""
    if mode != "frame":
        return np.ones(len(item.rows), bool)
    return hold.keep(item.rows[:, BOX], item.dynamic) if hold is not None else item.dynamic


def _static_boxes(item: FrameDetections, keep: np.ndarray, mode: str, tracker: DeepSort) -> np.ndarray:
    """(K, 4) boxes drawn as static: the tracks held static ("track"), else the detections the motion stage
    called static (a box held for a track is the track's, not static)."""
    if mode == "track":
        return tracker.static_tracks()[:, 1:5]
    static_mask = ~item.dynamic & ~keep if mode == "frame" else ~item.dynamic
    return item.rows[static_mask & (item.rows[:, CONF] >= tracker.min_confidence), BOX]


def _recording(stream: Iterator[FrameDetections], sink: list[FrameDetections]) -> Iterator[FrameDetections]:
    for item in stream:
        sink.append(item)
        yield item


FILTER_MODES = {"track": "track", "frame": "frame", True: "frame", False: "off", "off": "off"}


def filter_mode(value: object) -> str:
    """`dynamic_filter` of conf/track.yaml as one of "track", "frame" (also true) or "off" (also false)."""
    mode = FILTER_MODES.get(value) if isinstance(value, (bool, str)) else None
    if mode is None:
        raise ValueError(f"dynamic_filter must be track, frame (or true) or false, got {value!r}")
    return mode


def build_tracker(cfg: DictConfig) -> DeepSort:
    """The configured tracker (`tracker`), deciding per track what moves when `dynamic_filter` is track."""
    dynamics = instantiate(cfg.dynamic_track) if filter_mode(cfg.dynamic_filter) == "track" else None
    confirm = cfg.tracker.get("motion_confirm")
    if confirm is not None and dynamics is None:
        raise ValueError(
            f"tracker.motion_confirm={confirm} needs each box's motion flag, which only dynamic_filter=track "
            f"passes to the tracker (dynamic_filter is {cfg.dynamic_filter}; null turns motion_confirm off)"
        )
    if (
        confirm is not None
        and cfg.tracker.get("max_cosine_distance") is not None
        and confirm < cfg.get("reid_min_score", 0.0)
    ):
        raise ValueError(
            f"tracker.motion_confirm={confirm} is below reid_min_score={cfg.reid_min_score}: the boxes it "
            "confirms would reach the tracker with no appearance; set reid_min_score at or below it"
        )
    return instantiate(cfg.tracker, dynamics=dynamics)


@dataclass
class TrackingSetup:
    """How one source is tracked.

    make_stream: builds the `DetectionStream` (loads the networks) only if the cache cannot serve.
    make_motion_stream: builds a stream of the motion stage alone, for cached detections whose blobs were
        made by other motion settings.
    dynamic_filter: flags cached detections dynamic from their blobs (the stream has its own).
    mode (`filter_mode`): "frame", only detections that the motion stage marks dynamic reach the tracker
        (the paper) and, with a `DynamicHold` `hold`, those it holds for tracks the motion stage lost for
        a while; "track", every detection reaches the tracker with its flag and the tracker decides per
        track (it was built with `dynamics`); "off", every detection is tracked and output.
    offline: post-process the whole sequence's tracks (`tracking.offline`) before they are written and
        returned; the video shows the online ones. None: the online tracks.
    """

    tracker: DeepSort
    make_stream: Callable[[], DetectionStream]
    make_motion_stream: Callable[[], DetectionStream]
    dynamic_filter: DynamicFilter
    mode: str
    hold: DynamicHold | None = None
    offline: OfflineSettings | None = None


@dataclass
class SequenceOutput:
    """Where a tracked source goes: `<out_dir>/<name>.txt` (MOT) and, with `video`, `<name>.mp4`."""

    out_dir: Path
    video: bool
    progress: bool = True

    def paths(self, name: str) -> tuple[Path, Path | None]:
        return self.out_dir / f"{name}.txt", self.out_dir / f"{name}.mp4" if self.video else None

    def classes_path(self, name: str) -> Path:
        """`<name>.classes.json`: each track's voted class (`write_track_classes`)."""
        return self.out_dir / f"{name}.classes.json"


def run_source(
    source: FrameSource,
    setup: TrackingSetup,
    output: SequenceOutput,
    cache: DetectionCache | None = None,
    key: CacheKey | None = None,
) -> SequenceResult:
    """Track `source` as `setup` says and write it to `output`, from the detections `cache` holds under
    `key` where it has them (and into it where it has not)."""
    started = time.perf_counter()
    cached = cache.load(source.name, key) if cache is not None else None
    rerun_motion = cached is not None and cached.blobs is None  # made with other motion settings
    stream, timer, recorded = _detections(
        source, cached, setup, keep_images=output.video or setup.tracker.needs_images
    )
    # A live source has no length: the bar then shows the frame count and the live frame rate.
    bar = tqdm(stream, total=source.num_frames, desc=source.name, unit="frame",
               disable=not output.progress, leave=False)  # fmt: skip
    mot_path, video_path = output.paths(source.name)
    matched = setup.offline is not None and setup.offline.backfill
    rows_out, num_frames, matches, frame_classes = _track(
        bar, source, setup, timer, video_path=video_path, matched=matched
    )
    track_classes = setup.tracker.class_votes.table()
    if setup.offline is not None:
        rows_out, frame_classes = post_process(rows_out, matches, setup.offline), None
    write_mot_results(mot_path, rows_out)
    write_track_classes(output.classes_path(source.name), track_classes)
    if frame_classes is not None:  # the final vote, which the online rows only had so far
        final = np.array([track_classes.get(int(k), (UNKNOWN, 0.0))[0] for k in rows_out[:, 1]], dtype=int)
        frame_classes = np.column_stack([frame_classes[:, 0], final]).reshape(-1, 2)
    if cache is not None:
        _update_cache(cache, source.name, key, cached, recorded, rerun_motion, num_frames)
    return SequenceResult(
        name=source.name,
        rows=rows_out,
        num_frames=num_frames,
        from_cache=cached is not None,
        wall_seconds=time.perf_counter() - started,
        timings=timer.ms_per_frame(num_frames),
        mot_path=mot_path,
        video_path=video_path if video_path is not None and video_path.is_file() else None,
        classes=frame_classes,
        classes_path=output.classes_path(source.name),
    )


def write_track_classes(path: Path, track_classes: dict[int, tuple[int, float]]) -> None:
    """Write each track's voted class as JSON: `{"tracks": {"<id>": {"class": k, "name": ..., "share": s}}}`,
    the share being the class's part of the summed scores of the track's matched detections; `name` from
    `class_name`."""
    tracks = {
        str(k): {"class": c, "name": class_name(c), "share": round(share, 4)}
        for k, (c, share) in sorted(track_classes.items())
    }
    atomic_write_text(path, json.dumps({"tracks": tracks}, indent=1) + "\n")


def _detections(
    source: FrameSource,
    cached: CachedSequence | None,
    setup: TrackingSetup,
    *,
    keep_images: bool,
) -> tuple[Iterator[FrameDetections], StageTimer, list[FrameDetections]]:
    """The source's detections frame by frame, the timer of the stages that make them, and the list the
    frames of a fresh stream are recorded into (for the cache): cached detections as they are, cached
    detections with the motion stage alone run again (their blobs were made by other motion settings),
    or the whole stream."""
    recorded: list[FrameDetections] = []
    if cached is not None and cached.blobs is None:  # the motion stage alone, in step with the tracker
        motion_stream = setup.make_motion_stream()
        motion = motion_stream.run(source, keep_images=keep_images)
        return cached_frames(cached, setup.dynamic_filter, motion=motion), motion_stream.timer, recorded
    if cached is not None:
        images = source if keep_images else None
        return cached_frames(cached, setup.dynamic_filter, images), StageTimer(), recorded
    detection_stream = setup.make_stream()
    stream = _recording(detection_stream.run(source, keep_images=keep_images), recorded)
    return stream, detection_stream.timer, recorded


def _track(
    frames: Iterable[FrameDetections],
    source: FrameSource,
    setup: TrackingSetup,
    timer: StageTimer,
    *,
    video_path: Path | None,
    matched: bool = False,
) -> tuple[np.ndarray, int, np.ndarray | None, np.ndarray]:
    """Step the tracker through the frames: rows `frame, id, x, y, w, h` of its output, the frames seen,
    with `matched` (for offline backfill) the same rows of every track matched to a detection on each
    frame, and per output row the tracker's `output_classes` (the class of the frame's own detection,
    the track's vote so far). With `video_path`, the annotated frames are written there as they come
    (replacing it at the end), each track labelled with its class so far."""
    tracker, mode, hold = setup.tracker, setup.mode, setup.hold
    annotator, results, classes = Annotator(), [], []
    matches = [] if matched else None
    if hold is not None:
        hold.reset()
    with ExitStack() as stack:
        writer = None
        for item in frames:
            keep = _reaching_tracker(item, mode, hold)
            dets = item.rows[keep]
            rescue = getattr(tracker, "motion_rescue", False) and item.blobs is not None
            with timer("tracker"):
                out = tracker.step(
                    dets[:, BOX],
                    dets[:, CONF],
                    dets[:, FEATURES],
                    dynamic=item.dynamic[keep] if mode == "track" else None,
                    image=item.image,
                    classes=item.classes[keep],
                    **({"blobs": blob_boxes(item.blobs)} if rescue else {}),
                )
                named = tracker.output_classes()
            if hold is not None:
                hold.update(out)
            results.append(np.column_stack([np.full(len(out), item.frame), out]))
            classes.append(named)
            if matches is not None:
                on_frame = tracker.matched_tracks()
                matches.append(np.column_stack([np.full(len(on_frame), item.frame), on_frame]))
            if video_path is not None and item.image is not None:
                if writer is None:
                    height, width = item.image.shape[:2]
                    writer = stack.enter_context(VideoWriter(video_path, source.fps, (width, height)))
                static = _static_boxes(item, keep, mode, tracker)
                info = f"{source.name} frame {item.frame}  tracks {len(out)}"
                with timer("draw"):
                    writer.write(annotator(item.image, out, static, info, names=class_labels(named[:, 1])))
        if not results:
            raise ValueError(f"{source.description}: no frames")
        return (
            np.concatenate(results),
            len(results),
            np.concatenate(matches) if matches else None,
            np.concatenate(classes).reshape(-1, 2),
        )


def class_name(index: int) -> str | None:
    """The project's name of class `index` (`spacetrack.data.geometry.CLASS_NAMES`); None for UNKNOWN or an
    index outside them."""
    return CLASS_NAMES[index] if 0 <= index < len(CLASS_NAMES) else None


def class_labels(classes: np.ndarray) -> list[str]:
    """`class_name` of each index, empty where there is none (a label for the clip)."""
    return [class_name(int(k)) or "" for k in np.asarray(classes, dtype=int)]


def _update_cache(
    cache: DetectionCache,
    name: str,
    key: CacheKey,
    cached: CachedSequence | None,
    recorded: list[FrameDetections],
    rerun_motion: bool,
    num_frames: int,
) -> None:
    """Keep what this run made: a fresh stream's detections and blobs, or the blobs of a motion rerun."""
    if rerun_motion:
        cache.save_blobs(name, key, cached.blobs)
    if cached is None:
        det_rows = np.concatenate([r.rows for r in recorded])
        classes = np.concatenate([r.classes for r in recorded]).astype(np.int64)
        cache.save(name, key, det_rows, classes, num_frames=num_frames)
        cache.save_blobs(name, key, [r.blobs for r in recorded])
