"""`make demo`: build the small demo dataset and show it — a contact sheet and an annotated clip.

The clip puts each frame with its ground truth (red: moving targets with their ids and trails; green:
static objects; dashed grey: a target hidden behind another) beside the ground-truth motion mask.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import mlflow
import numpy as np
from omegaconf import DictConfig, OmegaConf

from spacetrack import build_data, cli, track
from spacetrack.config import compose_config
from spacetrack.data.layout import (
    BOX,
    CONF,
    FRAME,
    ID,
    MANIFEST,
    frame_name,
    frame_paths,
    load_manifest,
    read_mask,
    read_mot,
    read_rgb,
)
from spacetrack.mlflow_log import start_run
from spacetrack.viz.draw import draw_boxes, draw_trails
from spacetrack.viz.video import VideoWriter

MOVING, STATIC, HIDDEN = (255, 50, 50), (60, 230, 60), (150, 150, 150)


def dataset_is_current(cfg: DictConfig) -> bool:
    """Whether dataset_dir already holds the dataset this config would build (same data config and seed)."""
    path = Path(cfg.dataset_dir) / MANIFEST
    if not path.is_file():
        return False
    built = json.loads(path.read_text())["config"]
    wanted = OmegaConf.to_container(cfg, resolve=True)
    return built.get("data") == wanted["data"] and built.get("seed") == wanted["seed"]


def annotate(rgb: np.ndarray, rows: np.ndarray, statics: np.ndarray, trails: dict[int, list]) -> np.ndarray:
    """Frame with boxes: moving targets red with ids and trails, hidden ones grey, static objects green."""
    seen = rows[rows[:, CONF] > 0]
    out = draw_trails(rgb, {k: v for k, v in trails.items() if len(v) > 1}, color=MOVING)
    out = draw_boxes(out, seen[:, BOX], ids=seen[:, ID].astype(int).tolist(), color=MOVING)
    hidden = rows[rows[:, CONF] == 0]
    out = draw_boxes(out, hidden[:, BOX], labels=[f"{int(i)} hidden" for i in hidden[:, ID]], color=HIDDEN)
    return draw_boxes(out, statics[:, BOX], labels=["static"] * len(statics), color=STATIC)


def write_clip(root: Path, seq: dict, path: Path) -> int:
    """Annotated frames beside their motion masks, as an H.264 MP4; returns the number of frames."""
    d = root / seq["name"]
    gt, static = read_mot(d / "gt" / "gt.txt"), read_mot(d / "gt" / "static.txt")
    trails: dict[int, list] = {}
    frames = frame_paths(root, seq["name"])
    with VideoWriter(path, fps=seq["fps"], size=(2 * seq["width"], seq["height"])) as video:
        for frame, img_path in enumerate(frames, start=1):
            rgb = read_rgb(img_path)
            rows = gt[gt[:, FRAME] == frame]
            for _, tid, x, y, w, h, conf, *_ in rows:
                if conf > 0:
                    trails.setdefault(int(tid), []).append((x + w / 2, y + h / 2))
            left = annotate(rgb, rows, static[static[:, FRAME] == frame], trails)
            mask = read_mask(d / "masks" / frame_name(frame, "png"))
            video.write(np.hstack([left, np.dstack([mask] * 3)]))
    return len(frames)


def run_pipeline_on(cfg: DictConfig, seq: dict, out_dir: Path) -> dict[str, float]:
    """The whole pipeline (detector, re-ID, motion fusion, DeepSORT) on one sequence of the demo data."""
    overrides = [
        f"data_root={cfg.data_root}",
        f"sequence={seq['name']}",
        f"detector.weights={cfg.track.detector_weights}",
        f"reid.weights={cfg.track.reid_weights}",
        f"tracker={cfg.track.tracker}",
        f"output_dir={out_dir}",
        f"progress={cfg.progress}",
        "logger=mlflow" if cfg.logger.enabled else "logger=none",
        "logger.experiment=demo",
    ]
    track_cfg = compose_config("track", overrides)
    track_cfg.data = cfg.data  # the demo's dataset, whatever data config built it
    return track.run(track_cfg)


def run(cfg: DictConfig) -> dict[str, float]:
    if not dataset_is_current(cfg):
        build_data.run(OmegaConf.merge(cfg, {"overwrite": True}))
    root = Path(cfg.dataset_dir)
    manifest = load_manifest(root)
    demo_dir = Path(cfg.output_dir)
    demo_dir.mkdir(parents=True, exist_ok=True)
    sheet = demo_dir / "contact_sheet.jpg"
    shutil.copyfile(root / "contact_sheet.jpg", sheet)
    shutil.copyfile(root / "CARD.md", demo_dir / "CARD.md")
    seq = next(
        (s for s in manifest["sequences"] if s["scenario"] == cfg.clip_scenario), manifest["sequences"][0]
    )
    clip = demo_dir / f"{seq['name']}_ground_truth.mp4"
    frames = write_clip(root, seq, clip)
    with start_run(cfg, run_name="demo") as active:
        if active is not None:
            for artifact in (sheet, clip, demo_dir / "CARD.md"):
                mlflow.log_artifact(str(artifact))
    print(f"dataset: {root} ({len(manifest['sequences'])} sequences, card {root / 'CARD.md'})")
    print(f"contact sheet: {sheet}")
    print(f"clip: {clip} ({frames} frames, left: frame and ground truth, right: motion mask)")
    result = {"sequences": float(len(manifest["sequences"])), "clip_frames": float(frames)}
    if cfg.track.enabled:
        scores = run_pipeline_on(cfg, seq, demo_dir / "track")
        print(
            f"tracked: {demo_dir / 'track'} ({seq['name']}.txt, .mp4, metrics.json): "
            + ", ".join(f"{k}={v:.3f}" for k, v in scores.items() if k in ("mota", "idf1", "idsw", "fps"))
        )
        result.update(scores)
    return result


@cli.entry_point("demo", files="output_dir")
def main(cfg: DictConfig) -> dict[str, float]:
    result = run(cfg)
    return {k: result[k] for k in ("sequences", "mota", "idf1", "idsw") if k in result}


if __name__ == "__main__":
    main()
