"""What a tracked name's false positives and misses are, per scenario, from its MOT results on disk.

MOTA counts a false positive and a miss alike; this splits them by what lies under them, after the same
frame-by-frame matching that scores them (`spacetrack.evaluation.mot.accumulate`, IoU >= 0.5):

- a false positive is a **part** when at least `--inside` (0.8) of its area lies inside a target's box: a
  lit panel or the bright end of a dim rocket body boxed alone; **loose** when it overlaps a target's box
  otherwise (a target boxed too big, too small or shifted); **elsewhere** when it touches no target (a
  star, a flare, a parked object);
- a miss is **part-boxed** when a false positive of that frame is a part of it, **loosely boxed** when a
  false positive overlaps it otherwise, and **unboxed** when no unmatched result touches it (the detector
  or the tracker gave nothing there). Unboxed misses are counted again by the longer side of the target's
  box (below 16, 16-32, 32-64, 64 px and up) and by whether they fall in the first 10 frames since the
  target's first row of truth, where a tracker that confirms a track only after several hits misses it
  even on perfect boxes, and by whether they fall within 5 frames after the target's last match: a short
  gap in a live track, which a tracker could bridge, rather than a stretch where no track holds it.

A part and its part-boxed target are one event counted twice by MOTA. The results are those
`track_study.py` wrote (`outputs/<study>/<data>/<name>/fold<k>/<sequence>.txt`), so a tracked name's
folds must have been tracked on this machine; the ground truth is `data/<data>/<sequence>/gt/gt.txt`.
The table lands in `<study>/on_<data>/errors.md` (with `errors.json`, the counts per name, fold and
sequence).

    python experiments/detector_cv/error_breakdown.py --study psf_truth --data space_default_psf \
        --names gt_deepsort_paper gam_deepsort_paper_pipeline_low03_agnostic_part08 --reference finetune_lr
"""

from __future__ import annotations

import argparse
import json
import re
from collections import Counter
from pathlib import Path

import numpy as np

from spacetrack.config import REPO_ROOT
from spacetrack.data.layout import load_manifest, read_mot
from spacetrack.evaluation.mot import accumulate, scored_rows
from spacetrack.io import atomic_write_text
from spacetrack.motion.dynamic import coverage
from spacetrack.tracking.iou_matching import intersections

HERE = Path(__file__).resolve().parent
FP_KINDS = ("part", "loose", "elsewhere")
FN_KINDS = ("part_boxed", "loosely_boxed", "unboxed")
# Unboxed misses by the target's size (the longer side of its box, pixels: below 16, 16-32, 32-64, 64 and
# up) and by whether the miss falls in the target's first EARLY frames of truth (a track not yet confirmed).
SIZES = (
    (0, 16, "unboxed_lt16"),
    (16, 32, "unboxed_16_32"),
    (32, 64, "unboxed_32_64"),
    (64, np.inf, "unboxed_ge64"),
)
EARLY = 10
# ... and by whether it falls within GAP frames after the target's last match (a short gap in a live track,
# which a tracker could bridge, rather than a stretch where no track holds the target).
GAP = 5
UNBOXED_KINDS = (*(key for _, _, key in SIZES), "unboxed_early", "unboxed_gap")


def _first(kinds: tuple[str, str, str], first: bool, second: bool) -> str:
    """kinds[0] if `first`, else kinds[1] if `second`, else kinds[2]."""
    return kinds[0] if first else kinds[1] if second else kinds[2]


def breakdown(gt: np.ndarray, hyp: np.ndarray, *, iou_threshold: float = 0.5, inside: float = 0.8) -> Counter:
    """Counts of each FP_KINDS / FN_KINDS kind, of `matches` and of `switches` for one sequence's MOT
    arrays (ground truth with its visibility column, results), matched as the score matches them."""
    if not 0.0 < inside <= 1.0:
        raise ValueError(f"inside must lie in (0, 1], got {inside}")
    gt_keep, hyp_keep = scored_rows(gt, hyp, iou_threshold=iou_threshold)
    gt, hyp = gt[gt_keep], hyp[hyp_keep]
    events = accumulate(gt, hyp, iou_threshold=iou_threshold).mot_events
    counts = Counter({k: 0 for k in (*FP_KINDS, *FN_KINDS, *UNBOXED_KINDS, "matches", "switches")})
    counts["matches"] = int((events["Type"] == "MATCH").sum() + (events["Type"] == "SWITCH").sum())
    counts["switches"] = int((events["Type"] == "SWITCH").sum())
    gt_box = {(int(f), int(i)): b for f, i, b in zip(gt[:, 0], gt[:, 1], gt[:, 2:6], strict=True)}
    hyp_box = {(int(f), int(i)): b for f, i, b in zip(hyp[:, 0], hyp[:, 1], hyp[:, 2:6], strict=True)}
    first_seen = {int(i): int(gt[gt[:, 1] == i, 0].min()) for i in np.unique(gt[:, 1])}
    last_match: dict[int, int] = {}
    for frame in np.unique(np.concatenate([gt[:, 0], hyp[:, 0]])).astype(int):
        try:
            rows = events.loc[frame]
        except KeyError:
            continue
        fps = np.array([hyp_box[frame, int(h)] for h in rows.loc[rows["Type"] == "FP", "HId"]]).reshape(-1, 4)
        missed_ids = [int(o) for o in rows.loc[rows["Type"] == "MISS", "OId"]]
        misses = np.array([gt_box[frame, o] for o in missed_ids]).reshape(-1, 4)
        targets = gt[gt[:, 0] == frame, 2:6]
        on_target = intersections(fps, targets)[0] > 0
        part_of_target = coverage(fps, targets) >= inside
        for part, touches in zip(part_of_target.any(axis=1), on_target.any(axis=1), strict=True):
            counts[_first(FP_KINDS, part, touches)] += 1
        on_miss = intersections(fps, misses)[0] > 0
        part_of_miss = coverage(fps, misses) >= inside
        for box, target, part, touches in zip(
            misses, missed_ids, part_of_miss.any(axis=0), on_miss.any(axis=0), strict=True
        ):
            kind = _first(FN_KINDS, part, touches)
            counts[kind] += 1
            if kind == "unboxed":
                side = max(box[2], box[3])
                counts[next(key for low, high, key in SIZES if low <= side < high)] += 1
                counts["unboxed_early"] += int(frame - first_seen[target] < EARLY)
                counts["unboxed_gap"] += int(frame - last_match.get(target, -GAP - 1) <= GAP)
        for target in rows.loc[rows["Type"].isin(("MATCH", "SWITCH")), "OId"]:
            last_match[int(target)] = frame
    return counts


def scenarios(data: Path) -> dict[str, str]:
    """sequence -> scenario, as the dataset's manifest records them."""
    return {s["name"]: s["scenario"] for s in load_manifest(data)["sequences"]}


def name_counts(results: Path, data: Path, **kwargs) -> dict[int, dict[str, dict[str, int]]]:
    """fold -> sequence -> counts, for every `fold<k>/<sequence>.txt` under one tracked name's `results`."""
    out: dict[int, dict[str, dict[str, int]]] = {}
    for folder in sorted(results.glob("fold*")):
        match = re.fullmatch(r"fold(\d+)", folder.name)
        if match is None:
            continue
        for path in sorted(folder.glob("seq_*.txt")):
            gt_path = data / path.stem / "gt" / "gt.txt"
            if not gt_path.is_file():
                raise SystemExit(f"{path}: no ground truth for it at {gt_path}")
            counts = breakdown(read_mot(gt_path), read_mot(path), **kwargs)
            out.setdefault(int(match[1]), {})[path.stem] = dict(counts)
    return out


def write_tables(
    found: dict[str, dict[int, dict[str, dict[str, int]]]],
    out: Path,
    inside: float,
    scenario_of: dict[str, str],
) -> Path:
    """`errors.md` (one table per tracked name: a line per scenario of `scenario_of`, sequence -> scenario,
    and the total) and `errors.json`."""
    head = (
        "| scenario | sequences | matches | FP part | FP loose | FP elsewhere | miss part-boxed | "
        "miss loosely boxed | miss unboxed | switches |"
    )
    unboxed_head = (
        "| scenario | unboxed | < 16 px | 16-32 px | 32-64 px | >= 64 px | "
        f"in the target's first {EARLY} frames | within {GAP} frames of its last match |"
    )
    lines = [
        "False positives and misses of each tracked name, by what lies under them (written by "
        "`error_breakdown.py`; see its docstring): a false positive at least "
        f"{inside:g} inside a target's box is a part, one overlapping a target otherwise is loose, one "
        "touching no target is elsewhere; a miss is part-boxed, loosely boxed or unboxed by the false "
        "positives on it. Unboxed misses are also counted by the size of the target's box and by whether "
        f"they fall in the first {EARLY} frames of the target's truth (before a track of it can be confirmed) "
        f"or within {GAP} frames after the target's last match (a short gap in a live track).",
    ]
    for name, by_fold in found.items():
        by_scenario: dict[str, Counter] = {}
        sequences: Counter = Counter()
        for seqs in by_fold.values():
            for seq, counts in seqs.items():
                if seq not in scenario_of:
                    raise SystemExit(f"{name}: sequence {seq} is not in the dataset's manifest")
                by_scenario.setdefault(scenario_of[seq], Counter()).update(counts)
                sequences[scenario_of[seq]] += 1
        total = sum(by_scenario.values(), Counter())
        lines += [
            "",
            f"`{name}`, folds {', '.join(str(f) for f in sorted(by_fold))}:",
            "",
            head,
            "|---" * 10 + "|",
        ]
        for label, counts in [*sorted(by_scenario.items()), ("all", total)]:
            n = sum(sequences.values()) if label == "all" else sequences[label]
            cells = [counts["matches"], *(counts[k] for k in (*FP_KINDS, *FN_KINDS)), counts["switches"]]
            lines.append(f"| {label} | {n} | " + " | ".join(str(int(c)) for c in cells) + " |")
        lines += [
            "",
            "Its unboxed misses by target size (longer side) and age:",
            "",
            unboxed_head,
            "|---" * 8 + "|",
        ]
        for label, counts in [*sorted(by_scenario.items()), ("all", total)]:
            cells = [counts["unboxed"], *(counts[k] for k in UNBOXED_KINDS)]
            lines.append(f"| {label} | " + " | ".join(str(int(c)) for c in cells) + " |")
    out.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out / "errors.json", json.dumps(found, indent=1, sort_keys=True) + "\n")
    atomic_write_text(out / "errors.md", "\n".join(lines) + "\n")
    return out / "errors.md"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--study", required=True, help="a folder of experiments/detector_cv")
    parser.add_argument("--data", required=True, help="the dataset the names were tracked and scored on")
    parser.add_argument("--names", nargs="+", required=True, help="tracked names (a row and its --set label)")
    parser.add_argument("--reference", help="a study whose results to take for a name this one lacks")
    parser.add_argument("--inside", type=float, default=0.8, help="share of a part's area inside a target")
    args = parser.parse_args()
    folder = HERE / args.study
    if not folder.is_dir():
        raise SystemExit(f"--study {args.study}: {folder} is not a study folder")
    if not 0.0 < args.inside <= 1.0:
        raise SystemExit(f"--inside {args.inside}: must lie in (0, 1]")
    data = REPO_ROOT / "data" / args.data
    found = {}
    for name in args.names:
        studies = [args.study, *([args.reference] if args.reference else [])]
        results = next(
            (REPO_ROOT / "outputs" / s / args.data / name for s in studies
             if (REPO_ROOT / "outputs" / s / args.data / name).is_dir()),
            None,
        )  # fmt: skip
        if results is None:
            raise SystemExit(f"--names {name}: no results under outputs/{{{','.join(studies)}}}/{args.data}/")
        found[name] = name_counts(results, data, inside=args.inside)
        if not found[name]:
            raise SystemExit(f"{results}: no fold<k>/seq_*.txt results in it")
    print(write_tables(found, folder / f"on_{args.data}", args.inside, scenarios(data)))


if __name__ == "__main__":
    main()
