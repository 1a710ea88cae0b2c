"""Cross-validation folds by sequence, balanced by scenario."""

from __future__ import annotations

import numpy as np


def assign_folds(scenarios: list[str], num_folds: int, seed: int) -> list[int]:
    """Fold index (0..num_folds-1) of each sequence; a sequence is never split across folds.

    Sequences are shuffled within their scenario, then the scenarios are laid end to end and dealt to the
    folds in turn, like cards. Fold sizes differ by at most one, and each scenario is spread over as many
    folds as it has sequences, even when it has fewer sequences than there are folds (where scikit-learn's
    stratified splitters refuse).
    """
    n = len(scenarios)
    if n < num_folds:
        raise ValueError(
            f"{n} sequences cannot fill {num_folds} folds; set data.num_sequences >= {num_folds}"
        )
    rng = np.random.default_rng(seed)
    order = []
    for scenario in sorted(set(scenarios)):
        members = [i for i, s in enumerate(scenarios) if s == scenario]
        order.extend(rng.permutation(members).tolist())
    folds = [0] * n
    for position, index in enumerate(order):
        folds[index] = position % num_folds
    return folds
