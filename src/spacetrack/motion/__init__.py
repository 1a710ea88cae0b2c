"""Finding what moves: frame differences, ViBe, OpenCV peers, their fusion and dynamic-target identification.

Every detector streams: `apply(frame) -> mask | None`, `latency`, `mask_index`, `reset()` (see `frames`).
"""

from spacetrack.motion.blobs import Blob, find_blobs
from spacetrack.motion.difference import ThreeFrameDifference, TwoFrameDifference
from spacetrack.motion.dynamic import DynamicFilter
from spacetrack.motion.five_frame import FiveFrameDifference
from spacetrack.motion.frames import MotionDetector
from spacetrack.motion.fusion import Fusion
from spacetrack.motion.opencv_bg import KNN, MOG2
from spacetrack.motion.vibe import ViBe

__all__ = [
    "KNN",
    "MOG2",
    "Blob",
    "DynamicFilter",
    "FiveFrameDifference",
    "Fusion",
    "MotionDetector",
    "ThreeFrameDifference",
    "TwoFrameDifference",
    "ViBe",
    "find_blobs",
]
