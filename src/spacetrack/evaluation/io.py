"""Reading MOT text files (ground truth and tracker results) for evaluation: the dataset's reader."""

from __future__ import annotations

from spacetrack.data.layout import MOT_COLUMNS
from spacetrack.data.layout import read_mot as read_mot_file

__all__ = ["MOT_COLUMNS", "read_mot_file"]
