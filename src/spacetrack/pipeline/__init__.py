"""The whole system from frames to tracks (paper Figs. 1, 2 and 14).

enhancement -> detector (+ NMS) -> re-ID features -> motion fusion and dynamic-target identification ->
DeepSORT -> MOT results, annotated MP4 and per-stage timings. Detector boxes and re-ID features are cached
per sequence, so re-tracking with other settings never re-runs a network.
"""

from spacetrack.pipeline.cache import CacheKey, CacheMismatchError, DetectionCache
from spacetrack.pipeline.detector import GroundTruthDetector, YoloDetector
from spacetrack.pipeline.sources import FrameSource, open_source
from spacetrack.pipeline.stages import DetectionStream
from spacetrack.pipeline.timing import StageTimer

__all__ = [
    "CacheKey",
    "CacheMismatchError",
    "DetectionCache",
    "DetectionStream",
    "FrameSource",
    "GroundTruthDetector",
    "StageTimer",
    "YoloDetector",
    "open_source",
]
