"""Scoring tracker results against MOT ground truth: pure metric functions of MOT arrays (read them with
`spacetrack.data.layout.read_mot`)."""

from spacetrack.evaluation.mot import OVERALL, accumulate, evaluate, summarize

__all__ = ["OVERALL", "accumulate", "evaluate", "summarize"]
