"""The dataset card: counts, distributions and a contact sheet, written next to the data."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from spacetrack.data.layout import BOX, CONF, FRAME, ID, frame_name, read_mot, read_rgb, rendered_truth
from spacetrack.viz.draw import draw_boxes
from spacetrack.viz.sheet import contact_sheet, write_image


def occlusion_events(records: list[dict]) -> tuple[int, int]:
    """(runs of frames in which a target is partly hidden by another object, runs in which it is fully hidden)."""
    partial = full = 0
    by_target: dict[tuple, list[dict]] = {}
    for r in records:
        by_target.setdefault((r["sequence"], r["id"]), []).append(r)
    for rows in by_target.values():
        rows.sort(key=lambda r: r["frame"])
        was_partial = was_full = False
        for r in rows:
            is_partial = r["occluded_px"] > 0
            is_full = is_partial and r["visible_px"] == 0
            partial += is_partial and not was_partial
            full += is_full and not was_full
            was_partial, was_full = is_partial, is_full
    return partial, full


def statistics(records: list[dict], sequences: list[dict], class_names: list[str]) -> dict:
    """Counts per class, scenario and fold, box sizes, visibility and occlusion events."""
    labelled = [r for r in records if r["labelled"]]
    partial, full = occlusion_events([r for r in records if not r["static"]])
    sizes = np.array([np.sqrt(r["w"] * r["h"]) for r in labelled]) if labelled else np.zeros(0)
    return {
        "sequences": len(sequences),
        "frames": int(sum(s["num_frames"] for s in sequences)),
        "moving_targets": int(sum(s["num_targets"] for s in sequences)),
        "static_objects": int(sum(s["num_static"] for s in sequences)),
        "labels_per_class": {
            class_names[c]: n for c, n in sorted(Counter(r["class_id"] for r in labelled).items())
        },
        "sequences_per_scenario": dict(sorted(Counter(s["scenario"] for s in sequences).items())),
        "sequences_per_fold": {str(k): n for k, n in sorted(Counter(s["fold"] for s in sequences).items())},
        "gt_rows_moving": sum(1 for r in records if not r["static"]),
        "gt_rows_hidden": sum(1 for r in records if not r["static"] and r["visible_px"] == 0),
        "box_size_px": _quantiles(sizes),
        "visibility": _quantiles(np.array([r["visibility"] for r in records if not r["static"]])),
        "occlusion_events_partial": partial,
        "occlusion_events_full": full,
    }


def _quantiles(x: np.ndarray) -> dict[str, float]:
    if x.size == 0:
        return {}
    q = np.percentile(x, [0, 5, 50, 95, 100])
    return dict(zip(["min", "p5", "median", "p95", "max"], (round(float(v), 3) for v in q), strict=True))


def plot_distributions(records: list[dict], path: Path) -> None:
    labelled = [r for r in records if r["labelled"]]
    fig = Figure(figsize=(10, 3.5))
    axes = fig.subplots(1, 2)
    axes[0].hist([np.sqrt(r["w"] * r["h"]) for r in labelled], bins=40, color="tab:blue")
    axes[0].set(xlabel="box size sqrt(w*h) [px]", ylabel="labels", title="Box sizes (labelled targets)")
    axes[1].hist(
        [r["visibility"] for r in records if not r["static"]], bins=20, range=(0, 1), color="tab:red"
    )
    axes[1].set(xlabel="visibility", ylabel="ground-truth rows", title="Visibility (moving targets)")
    fig.tight_layout()
    fig.savefig(path, dpi=100)


def write_contact_sheet(
    root: Path, sequences: list[dict], image_ext: str, path: Path, tiles: int = 12
) -> None:
    """A grid of mid-sequence frames with ground-truth boxes: red moving targets, green static objects."""
    images, captions = [], []
    for seq in sequences[:tiles]:
        frame = seq["num_frames"] // 2
        rgb = read_rgb(root / seq["name"] / "img" / frame_name(frame, image_ext))
        for gt_file, colour in (("gt.txt", (255, 40, 40)), ("static.txt", (40, 255, 40))):
            rows = read_mot(root / seq["name"] / "gt" / gt_file)
            rows = rows[(rows[:, FRAME] == frame) & (rows[:, CONF] > 0)]
            rgb = draw_boxes(rgb, rows[:, BOX], ids=rows[:, ID].astype(int).tolist(), color=colour)
        images.append(rgb)
        captions.append(f"{seq['name']} f{frame} fold {seq['fold']}")
    sheet = contact_sheet(
        images, cols=min(4, len(images)), labels=captions, tile_width=min(480, images[0].shape[1])
    )
    write_image(path, sheet)


_TRUTH_WORDS = {
    "silhouette": "whole silhouette, lit or not (`data.truth=silhouette`)",
    "seen": "pixels the camera shows: those standing out from what lies behind them (`data.truth=seen`)",
}


def card_markdown(manifest: dict, stats: dict) -> str:
    lines = [
        f"# Dataset card: {manifest['name']}",
        "",
        f"Rendered by `python -m spacetrack.build_data` (seed {manifest['config']['seed']}); "
        f"content hash `{manifest['content_hash']}`.",
        "",
        f"- {stats['sequences']} sequences, {stats['frames']} frames of "
        f"{manifest['width']}x{manifest['height']} at {manifest['fps']} fps, {manifest['num_folds']} folds",
        f"- {stats['moving_targets']} moving targets, {stats['static_objects']} static objects",
        f"- classes: {', '.join(manifest['class_names'])}",
        f"- truth boxes frame each object's {_TRUTH_WORDS[rendered_truth(manifest)]}",
        f"- ground-truth rows of moving targets: {stats['gt_rows_moving']}, of which fully hidden: "
        f"{stats['gt_rows_hidden']}",
        f"- occlusion events (runs of frames a target is hidden by another object): "
        f"{stats['occlusion_events_partial']} partial, {stats['occlusion_events_full']} complete",
        "",
        "| labels per class | count |",
        "|---|---|",
        *[f"| {k} | {v} |" for k, v in stats["labels_per_class"].items()],
        "",
        "| sequences per scenario | count |",
        "|---|---|",
        *[f"| {k} | {v} |" for k, v in stats["sequences_per_scenario"].items()],
        "",
        "| fold | " + " | ".join(stats["sequences_per_fold"]) + " |",
        "|---|" + "---|" * len(stats["sequences_per_fold"]),
        "| sequences | " + " | ".join(str(v) for v in stats["sequences_per_fold"].values()) + " |",
        "",
        "| distribution | min | p5 | median | p95 | max |",
        "|---|---|---|---|---|---|",
        *[
            f"| {name} | " + " | ".join(str(v) for v in stats[key].values()) + " |"
            for name, key in (("box size sqrt(w*h) [px]", "box_size_px"), ("visibility", "visibility"))
            if stats[key]
        ],
        "",
        "![distributions](card_stats.png)",
        "",
        "![contact sheet](contact_sheet.jpg)",
        "",
    ]
    return "\n".join(lines)
