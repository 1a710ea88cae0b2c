"""Scoring tracker results against MOT ground truth: pure metric functions and a file reader."""

from spacetrack.evaluation.io import read_mot_file
from spacetrack.evaluation.mot import OVERALL, accumulate, evaluate, summarize

__all__ = ["OVERALL", "accumulate", "evaluate", "read_mot_file", "summarize"]
