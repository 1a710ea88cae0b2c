"""DeepSORT (paper eqs. 5-15, Table 2) on detections with appearance features; numpy + scipy only."""

from spacetrack.tracking.deepsort import DeepSort, track_sequence
from spacetrack.tracking.detection import Detections
from spacetrack.tracking.tracker import Tracker

__all__ = ["DeepSort", "Detections", "Tracker", "track_sequence"]
