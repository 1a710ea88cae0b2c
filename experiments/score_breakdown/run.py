"""Where the score goes: every FN and FP of tracker results split by cause, per scenario, with the ground truth.

    python experiments/score_breakdown/run.py --results outputs/table4/gt_deepsort_original --name gt_deepsort_original
    python experiments/score_breakdown/run.py --dataset data/slew --results outputs/slew/track --name slew_track

`--results` holds MOT files `<seq>.txt` (or `fold<k>/<seq>.txt` below it, as the Table 4 runner writes
them); `--dataset` the sequences with `gt/gt.txt` and `gt/static.txt`. Matching is the evaluation's
(`spacetrack.evaluation.mot.accumulate`, IoU >= 0.5, fully hidden rows ignored). Causes:

- FN: `start` (a target's first visible run, before its first output: confirmation `n_init` and the
  dynamic decision), `never` (a target never output at all: held static or never confirmed),
  `after_hidden` (a run after the target was hidden or out of view, before it is output again, the gap
  since its last output <= `max_age`), `beyond_max_age` (the same, gap > `max_age`), `mid` (after it was
  output in the same run);
- FP: `parked` (IoU >= 0.5 with a parked object, `gt/static.txt`), `duplicate` (IoU >= 0.5 with a target
  that another output covers), `after_left` (the output's target is hidden or gone), `off` (the rest);
- complete occlusions: a target fully hidden (conf 0) between two visible frames; `same_id` when the
  output identity before and after is the same, `switched` when not, `not_reacquired` when the target
  is not output again in its next visible run.

Writes `<name>.json` and `<name>.md` here (atomically).
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np

from spacetrack.data.layout import load_manifest, read_mot
from spacetrack.evaluation.mot import accumulate, ignored_rows
from spacetrack.io import atomic_write_text
from spacetrack.tracking.iou_matching import iou_matrix

HERE = Path(__file__).resolve().parent
FN_CAUSES = ("start", "never", "after_hidden", "beyond_max_age", "mid")
FP_CAUSES = ("parked", "duplicate", "after_left", "off")
OCCLUSION = ("events", "same_id", "switched", "not_reacquired")


def _read(path: Path) -> np.ndarray:
    """(N, 9) MOT rows of `path`; none when it does not exist (a sequence without parked objects)."""
    return read_mot(path) if path.is_file() else np.zeros((0, 9))


def _matches(events) -> dict[tuple[int, int], int]:
    """{(frame, gt id): hypothesis id} of the matched pairs."""
    hit = events[events.Type.isin(["MATCH", "SWITCH"])]
    return {(int(f), int(o)): int(h) for (f, _), o, h in zip(hit.index, hit.OId, hit.HId, strict=True)}


def _fn_cause(frame: int, target: int, visible: np.ndarray, matched: dict, max_age: int) -> str:
    """Why ground-truth `target` is missed at `frame`; `visible`: sorted frames where it counts."""
    own = sorted(f for f, o in matched if o == target)
    if not own:
        return "never"
    run_start = frame
    while run_start - 1 in set(visible.tolist()):
        run_start -= 1
    if any(run_start <= f < frame for f in own):
        return "mid"
    before = [f for f in own if f < run_start]
    if run_start == visible[0] or not before:
        return "start"
    return "after_hidden" if frame - before[-1] <= max_age else "beyond_max_age"


def _occlusions(gt: np.ndarray, matched: dict) -> Counter:
    """Complete occlusions of each target (hidden rows between visible ones) and what became of its id."""
    out: Counter = Counter()
    for target in np.unique(gt[:, 1]).astype(int):
        rows = gt[gt[:, 1] == target]
        hidden = rows[:, 6] == 0
        frames = rows[:, 0].astype(int)
        for i in np.flatnonzero(hidden[1:] & ~hidden[:-1]) + 1:  # a hidden run starts at i
            after = np.flatnonzero(~hidden[i:])
            if not len(after):
                continue
            out["events"] += 1
            before_ids = [matched[(f, target)] for f in frames[:i][~hidden[:i]] if (f, target) in matched]
            end = i + after[0]
            run = frames[end:][np.cumprod(~hidden[end:]).astype(bool)]
            after_ids = [matched[(f, target)] for f in run if (f, target) in matched]
            if not after_ids:
                out["not_reacquired"] += 1
            elif before_ids and before_ids[-1] == after_ids[0]:
                out["same_id"] += 1
            else:
                out["switched"] += 1
    return out


def breakdown(gt: np.ndarray, static: np.ndarray, hyp: np.ndarray, max_age: int) -> dict[str, Counter]:
    """FN and FP causes and complete occlusions of one sequence (MOT arrays, `gt` with visibility)."""
    events = accumulate(gt, hyp).mot_events
    matched = _matches(events)
    keep = ~ignored_rows(gt)
    visible = {int(t): np.sort(gt[keep & (gt[:, 1] == t), 0].astype(int)) for t in np.unique(gt[:, 1])}
    fn, fp = Counter(), Counter()
    for (frame, _), target in events[events.Type == "MISS"].OId.items():
        fn[_fn_cause(int(frame), int(target), visible[int(target)], matched, max_age)] += 1
    last_target = {}  # hypothesis id -> the target it last covered
    for (frame, _), row in events.iterrows():
        if row.Type in ("MATCH", "SWITCH"):
            last_target[int(row.HId)] = int(row.OId)
            continue
        if row.Type != "FP":
            continue
        frame, h = int(frame), int(row.HId)
        box = hyp[(hyp[:, 0] == frame) & (hyp[:, 1] == h), 2:6]
        parked = static[static[:, 0] == frame, 2:6]
        targets = gt[(gt[:, 0] == frame) & keep]
        if len(parked) and iou_matrix(box, parked).max() >= 0.5:
            fp["parked"] += 1
        elif len(targets) and iou_matrix(box, targets[:, 2:6]).max() >= 0.5:
            fp["duplicate"] += 1
        elif h in last_target and last_target[h] not in set(targets[:, 1].astype(int).tolist()):
            fp["after_left"] += 1
        else:
            fp["off"] += 1
    idsw = int((events.Type == "SWITCH").sum())
    return {"fn": fn, "fp": fp, "occlusion": _occlusions(gt, matched), "idsw": Counter({"idsw": idsw})}


def _hypothesis_file(results: Path, name: str) -> Path | None:
    found = [results / f"{name}.txt", *sorted(results.glob(f"fold*/{name}.txt"))]
    return next((p for p in found if p.is_file()), None)


def run(dataset: Path, results: Path, max_age: int) -> dict[str, dict[str, dict[str, int]]]:
    """{scenario (and "all"): {"fn" | "fp" | "occlusion" | "idsw": {cause: count}}} over the sequences
    of `dataset` that have results under `results`."""
    totals: dict[str, dict[str, Counter]] = {}
    for seq in load_manifest(dataset)["sequences"]:
        path = _hypothesis_file(results, seq["name"])
        if path is None:
            continue
        gt_dir = dataset / seq["name"] / "gt"
        parts = breakdown(_read(gt_dir / "gt.txt"), _read(gt_dir / "static.txt"), _read(path), max_age)
        for scenario in (seq["scenario"], "all"):
            into = totals.setdefault(scenario, {k: Counter() for k in parts})
            for kind, counts in parts.items():
                into[kind].update(counts)
    return {s: {k: dict(c) for k, c in parts.items()} for s, parts in sorted(totals.items())}


def table(result: dict, title: str) -> str:
    columns = [("fn", c) for c in FN_CAUSES] + [("fp", c) for c in FP_CAUSES] + [("idsw", "idsw")]
    columns += [("occlusion", c) for c in OCCLUSION]
    lines = [f"# {title}", "", "| scenario | " + " | ".join(f"{k} {c}" for k, c in columns) + " |"]
    lines.append("|---|" + "---|" * len(columns))
    for scenario, parts in result.items():
        cells = [str(parts.get(k, {}).get(c, 0)) for k, c in columns]
        lines.append(f"| {scenario} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--dataset", default="data/space_default", type=Path)
    parser.add_argument(
        "--results", required=True, type=Path, help="folder of <seq>.txt or fold<k>/<seq>.txt"
    )
    parser.add_argument("--name", required=True, help="output files <name>.json and <name>.md")
    parser.add_argument("--max-age", type=int, default=70, help="the tracker's max_age (frames)")
    args = parser.parse_args()
    result = run(args.dataset, args.results, args.max_age)
    if not result:
        parser.error(f"no results for any sequence of {args.dataset} under {args.results}")
    record = {"dataset": str(args.dataset), "results": str(args.results), "max_age": args.max_age, **result}
    atomic_write_text(HERE / f"{args.name}.json", json.dumps(record, indent=2) + "\n")
    atomic_write_text(HERE / f"{args.name}.md", table(result, f"{args.name}: FN, FP and occlusions by cause"))
    print(table(result, args.name))


if __name__ == "__main__":
    main()
