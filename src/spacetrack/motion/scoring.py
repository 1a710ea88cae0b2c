"""Scoring the motion detectors on a rendered dataset: frames and truth masks read from disk, every method
run over every selected sequence, scores per scenario and a contact sheet of their masks.

All methods are scored on the same frames (from `warmup` to the last frame every method has a mask
for). Every method runs as configured (our methods with `compensate: auto`: global motion compensation
once the scene is found to move); scenarios in `compensate_scenarios` are scored twice more, as
`<scenario>_off` and `<scenario>_gmc`, with compensation switched off and on from the first frame for
the methods that have it. The overall score pools the rows as configured.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from spacetrack.data.layout import (
    BOX,
    CONF,
    FRAME,
    VISIBILITY,
    frame_paths,
    load_manifest,
    read_mask,
    read_mot,
    read_rgb,
)
from spacetrack.motion.evaluation import MotionScore
from spacetrack.motion.frames import to_grey
from spacetrack.viz.sheet import contact_sheet, write_image

log = logging.getLogger(__name__)

OVERALL = "overall"
METRICS = (
    "pixel_f1",
    "lit_f1",
    "blob_recall",
    "blob_precision",
    "dynamic_recall",
    "static_rejection",
    "pixel_precision",
    "pixel_recall",
)


def build_methods(methods: DictConfig, *, compensate: bool | None = None) -> dict:
    """{name: detector}; with `compensate` true or false, every `compensate` key in a method's config
    (its parts' too) is set to it; None keeps the configured values."""

    def switch(node: object) -> None:
        if isinstance(node, dict):
            if "compensate" in node:
                node["compensate"] = compensate
            for value in node.values():
                switch(value)

    detectors = {}
    for name, method_cfg in methods.items():
        plain = OmegaConf.to_container(method_cfg, resolve=True)
        if compensate is not None:
            switch(plain)
        detectors[name] = instantiate(plain)
    return detectors


def read_truth_mask(seq_dir: Path, index: int, shape: tuple[int, int]) -> np.ndarray:
    """Ground-truth motion mask of 0-based frame `index` (masks/ is 1-based)."""
    path = seq_dir / "masks" / f"{index + 1:06d}.png"
    mask = read_mask(path)
    if mask.shape != shape:
        raise ValueError(f"{path}: mask of shape {mask.shape}, the frames are {shape}")
    return mask


def target_boxes(gt: np.ndarray, min_visibility: float) -> dict[int, np.ndarray]:
    """{0-based frame: (N, 4) tlwh boxes of the visible objects} from MOT rows (gt.txt or static.txt)."""
    visible = gt[(gt[:, CONF] > 0) & (gt[:, VISIBILITY] >= min_visibility)]
    return {int(f) - 1: visible[visible[:, FRAME] == f, BOX] for f in np.unique(visible[:, FRAME])}


def mask_overlay(mask: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """RGB picture of a mask against the truth: white found, red false, blue missed."""
    pred, true = mask > 0, truth > 0
    out = np.zeros((*mask.shape, 3), np.uint8)
    out[pred & true] = (255, 255, 255)
    out[pred & ~true] = (255, 40, 40)
    out[~pred & true] = (60, 110, 255)
    return out


def score_sequence(cfg: DictConfig, seq_dir: Path, detectors: dict, sheet_at: float) -> tuple[dict, list]:
    """({method: MotionScore}, side-by-side tiles at `sheet_at` of the scored frames) for one sequence."""
    paths = frame_paths(seq_dir.parent, seq_dir.name, cfg.image_dir)
    if cfg.max_frames:
        paths = paths[: cfg.max_frames]
    boxes = target_boxes(read_mot(seq_dir / "gt" / "gt.txt"), cfg.min_visibility)
    static_path = seq_dir / "gt" / "static.txt"
    statics = target_boxes(read_mot(static_path), cfg.min_visibility) if static_path.is_file() else {}
    dynamic = instantiate(cfg.dynamic)
    latency = max(d.latency for d in detectors.values())
    first, last = max(cfg.warmup, latency), len(paths) - 1 - latency
    if last < first:
        raise ValueError(
            f"{seq_dir}: {len(paths)} frames are too few to score (warmup {first}, latency {latency})"
        )
    sheet_index = first + round(sheet_at * (last - first))
    scores = {name: MotionScore() for name in detectors}
    truths: dict[int, np.ndarray] = {}
    darks: dict[int, np.ndarray] = {}
    tiles: dict[str, np.ndarray] = {}
    for i, path in enumerate(paths):
        frame = read_rgb(path)
        truths[i] = read_truth_mask(seq_dir, i, frame.shape[:2])
        darks[i] = to_grey(frame) < cfg.dark_level
        truths.pop(i - latency - 1, None)
        darks.pop(i - latency - 1, None)
        if i == sheet_index:
            tiles["frame"], tiles["ground truth"] = frame, mask_overlay(truths[i], truths[i])
        for name, detector in detectors.items():
            mask = detector.apply(frame)
            t = detector.mask_index
            if mask is None or not first <= t <= last:
                continue
            no_targets = np.zeros((0, 4))
            scores[name].add_frame(
                mask,
                truths[t],
                boxes.get(t, no_targets),
                dark=darks[t],
                static_boxes=statics.get(t, no_targets),
                dynamic=dynamic,
                blob_iou=cfg.blob_iou,
                min_blob_area=cfg.min_blob_area,
            )
            if t == sheet_index:
                tiles[name] = mask_overlay(mask, truths[t])
    return scores, [(label, tiles[label]) for label in ("frame", "ground truth", *detectors)]


def json_safe(tree: object) -> object:
    """`tree` with NaN floats (undefined rates) replaced by None, so the file is strict JSON (null)."""
    if isinstance(tree, dict):
        return {k: json_safe(v) for k, v in tree.items()}
    if isinstance(tree, list):
        return [json_safe(v) for v in tree]
    return None if isinstance(tree, float) and tree != tree else tree


def markdown(results: dict[str, dict[str, dict[str, float]]], methods: list[str]) -> str:
    """One markdown table per metric: a row per scenario, a column per method; "-" where undefined."""
    parts = []
    for metric in METRICS:
        lines = [
            f"### {metric}",
            "",
            "| scenario | " + " | ".join(methods) + " |",
            "|" + "---|" * (len(methods) + 1),
        ]
        # pixel F1 gets the ceiling of a mask of the visible truth pixels (the same for every method)
        ceiling = metric == "pixel_f1"
        if ceiling:
            lines[2] += " visible ceiling |"
            lines[3] += "---|"
        for label, by_method in results.items():
            values = [by_method[m][metric] for m in methods]
            best = max((v for v in values if v == v), default=None)
            cells = ["-" if v != v else f"**{v:.3f}**" if v == best else f"{v:.3f}" for v in values]
            if ceiling:
                cells.append(f"{by_method[methods[0]]['pixel_f1_ceiling']:.3f}")
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        parts.append("\n".join(lines))
    return "\n\n".join(parts) + "\n"


def scoring_rows(cfg: DictConfig, root: Path) -> list[tuple[str, list[str], bool | None]]:
    """The rows to score, as (label, sequence names, compensate): every selected scenario as configured
    (compensate None), then `<scenario>_off` and `<scenario>_gmc` for those in `compensate_scenarios`.
    A scenario the dataset at `root` lacks is an error."""
    by_scenario: dict[str, list[str]] = {}
    for seq in load_manifest(root)["sequences"]:
        by_scenario.setdefault(seq["scenario"], []).append(seq["name"])
    wanted = list(cfg.scenarios) if cfg.scenarios else list(by_scenario)
    missing = [s for s in wanted if s not in by_scenario]
    if missing:
        raise ValueError(f"{root}: no sequences of scenario(s) {missing}; it has {sorted(by_scenario)}")
    variants: list[tuple[str, str, bool | None]] = [(s, s, None) for s in wanted]
    both = [s for s in wanted if s in cfg.compensate_scenarios]
    variants += [(f"{s}_{tag}", s, on) for s in both for tag, on in (("off", False), ("gmc", True))]
    return [(label, by_scenario[s][: cfg.max_sequences or None], on) for label, s, on in variants]


def score_rows(
    cfg: DictConfig, root: Path, rows: list[tuple[str, list[str], bool | None]], out_dir: Path
) -> dict[str, dict[str, dict[str, float]]]:
    """{row label: {method: `MotionScore.summary()`}} of every method of `cfg.methods` on the `rows`
    (see `scoring_rows`), with `OVERALL` pooled over the rows scored as configured; a contact sheet of
    each row's first sequence goes to `out_dir`."""
    totals: dict[str, dict[str, MotionScore]] = {}
    overall: dict[str, MotionScore] = {}
    for label, names, compensate in rows:
        totals[label] = {}
        for k, name in enumerate(names):
            detectors = build_methods(cfg.methods, compensate=compensate)
            scores, tiles = score_sequence(cfg, root / name, detectors, cfg.sheet_position)
            for method, score in scores.items():
                totals[label][method] = totals[label].get(method, MotionScore()).merge(score)
            f1 = {m: round(s.summary()["pixel_f1"], 3) for m, s in scores.items()}
            log.info("%s %s pixel F1: %s", label, name, f1)
            if k == 0:
                write_sheet(out_dir / f"sheet_{label}.jpg", tiles, f"{label} / {name}")
        if compensate is None:
            for method, score in totals[label].items():
                overall[method] = overall.get(method, MotionScore()).merge(score)
    results = {label: {m: s.summary() for m, s in row.items()} for label, row in totals.items()}
    results[OVERALL] = {m: s.summary() for m, s in overall.items()}
    return results


def write_sheet(path: Path, tiles: list[tuple[str, np.ndarray]], title: str) -> None:
    """Tile (label, RGB image) pairs three to a row and write them as JPEG."""
    labels = [f"{title}: {label}" if i == 0 else label for i, (label, _) in enumerate(tiles)]
    sheet = contact_sheet([image for _, image in tiles], cols=3, labels=labels, tile_width=320)
    write_image(path, sheet)
