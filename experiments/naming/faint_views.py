"""How often a dataset shows an object only in small part: per class, the objects with many labelled
frames in which less than a given share of them is seen.

A detector learns to name what its training data shows. Fold 2's dim rocket body is seen only by its
lit end cap (under a fifth of it) in all its labelled frames; this counts how many objects of each
class a dataset shows that way, so the training folds and the pretraining set can be compared.

    python experiments/naming/faint_views.py data/space_default_psf data/space_pretrain_seen \\
        --out experiments/naming/second_stage/faint_views.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from spacetrack.data.layout import load_manifest
from spacetrack.io import atomic_write_text
from spacetrack.reid.dataset import collect_crops


def faint_objects(root: Path, *, max_visibility: float, min_frames: int) -> tuple[dict, list[dict]]:
    """({class: objects}, [one row per object with at least `min_frames` labelled frames seen less than
    `max_visibility` of it]) over every sequence of the dataset at `root`, moving and parked objects."""
    manifest = load_manifest(root)
    names = list(manifest["class_names"])
    fold = {s["name"]: s["fold"] for s in manifest["sequences"]}
    # every labelled row (conf > 0) of known visibility, whatever its size
    table = collect_crops(root, list(fold), min_visibility=0.0, min_box_size=0.0, include_static=True)
    totals, faint = dict.fromkeys(names, 0), []
    for identity, (seq, object_id) in enumerate(table.names):
        mine = table.identity == identity
        name = names[int(table.object_class[mine][0])]
        totals[name] += 1
        low = int((table.visibility[mine] < max_visibility).sum())
        if low >= min_frames:
            faint.append({"sequence": seq, "fold": fold[seq], "id": object_id, "class": name,
                          "labelled_frames": int(mine.sum()), "faint_frames": low,
                          "median_visibility": round(float(np.median(table.visibility[mine])), 3)})  # fmt: skip
    return totals, faint


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("datasets", nargs="+", type=Path)
    parser.add_argument("--max-visibility", type=float, default=0.2)
    parser.add_argument("--min-frames", type=int, default=30)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    out = {"max_visibility": args.max_visibility, "min_frames": args.min_frames, "datasets": {}}
    for root in args.datasets:
        totals, faint = faint_objects(root, max_visibility=args.max_visibility, min_frames=args.min_frames)
        out["datasets"][root.name] = {"objects": totals, "faint": faint}
        counts = {c: sum(f["class"] == c for f in faint) for c in totals}
        print(f"{root.name}: objects {totals}, seen under {args.max_visibility} in >= {args.min_frames} "
              f"labelled frames {counts}")  # fmt: skip
    atomic_write_text(args.out, json.dumps(out, indent=2) + "\n")


if __name__ == "__main__":
    main()
