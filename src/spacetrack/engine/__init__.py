"""Detector training: loss and target assignment, optimisation, validation metrics, checkpoints."""
