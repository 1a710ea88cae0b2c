"""Synthetic space-scene datasets: rendering, ground truth, folds and the on-disk layout."""
