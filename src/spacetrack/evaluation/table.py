"""Human-readable rendering of evaluation results."""

from __future__ import annotations

from collections.abc import Mapping

COLUMNS = ("mota", "hota", "deta", "assa", "motp", "idf1", "idsw", "fp", "fn", "mt", "ml", "precision", "recall")  # fmt: skip
_FRACTIONS = {"hota", "deta", "assa", "mota", "motp", "idf1", "precision", "recall"}


def format_table(results: Mapping[str, Mapping[str, float]]) -> str:
    """A markdown table, one row per sequence: fractions as percentages, counts as integers."""

    def cell(key: str, value: float) -> str:
        if value != value:  # NaN: no match at all, so MOTP is undefined
            return "-"
        return f"{100 * value:.2f}" if key in _FRACTIONS else str(int(value))

    header = ["sequence", *(c.upper() for c in COLUMNS)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for name, metrics in results.items():
        lines.append("| " + " | ".join([name, *(cell(c, metrics[c]) for c in COLUMNS)]) + " |")
    return "\n".join(lines) + "\n"
