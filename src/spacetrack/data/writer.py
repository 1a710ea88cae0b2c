"""Writing one rendered sequence in the dataset layout (see `spacetrack.data.layout`)."""

from __future__ import annotations

from collections.abc import Callable
from configparser import ConfigParser
from pathlib import Path

import cv2
import numpy as np

from spacetrack.data.layout import frame_name
from spacetrack.data.render import FrameTruth, SequenceRenderer, TruthRow
from spacetrack.data.scene import ScenePlan
from spacetrack.viz.sheet import encode_image

Enhancer = Callable[[np.ndarray], np.ndarray]


def encode_mask(mask: np.ndarray) -> bytes:
    """A boolean mask as a single-channel PNG, 255 on True."""
    ok, buf = cv2.imencode(".png", mask.astype(np.uint8) * 255, [cv2.IMWRITE_PNG_COMPRESSION, 3])
    if not ok:
        raise RuntimeError(f"OpenCV could not encode a {mask.shape} mask as PNG")
    return buf.tobytes()


def mot_line(frame: int, row: TruthRow) -> str:
    """`frame,id,x,y,w,h,conf,class,visibility`; conf is 0 for a target hidden in this frame (ignored)."""
    conf = 1 if row.visible_px > 0 else 0
    return f"{frame},{row.id},{row.x},{row.y},{row.w},{row.h},{conf},{row.class_id},{row.visibility:.4f}"


def yolo_lines(truth: FrameTruth, width: int, height: int, min_pixels: int) -> list[str]:
    """`class cx cy w h` (normalised) for every target with at least `min_pixels` visible pixels."""
    out = []
    for r in truth.rows:
        if r.visible_px >= min_pixels:
            cx, cy = (r.x + r.w / 2) / width, (r.y + r.h / 2) / height
            out.append(f"{r.class_id} {cx:.6f} {cy:.6f} {r.w / width:.6f} {r.h / height:.6f}")
    return out


def write_sequence(
    plan: ScenePlan,
    seq_dir: Path,
    *,
    fps: float,
    image_ext: str,
    jpeg_quality: int,
    label_min_pixels: int,
    enhancers: list[tuple[str, Enhancer]] = (),
    progress: Callable[[int], None] | None = None,
    truth: str = "silhouette",
    seen_snr: float = 3.0,
) -> list[dict]:
    """Render every frame of `plan` into `seq_dir` and return the per-target truth records for statistics.
    `truth` and `seen_snr`: which pixels of an object its labels count (see `spacetrack.data.render`)."""
    cam = plan.camera
    folders = ["img", "gt", "labels", "masks"] + [f"img_{name}" for name, _ in enhancers]
    for folder in folders:
        (seq_dir / folder).mkdir(parents=True)
    renderer = SequenceRenderer(plan, truth=truth, seen_snr=seen_snr)
    moving_lines, static_lines, records = [], [], []
    for t in range(plan.num_frames):
        frame = t + 1
        rgb, truth = renderer.render(t)
        (seq_dir / "img" / frame_name(frame, image_ext)).write_bytes(
            encode_image(rgb, image_ext, jpeg_quality)
        )
        for name, enhance in enhancers:
            out = seq_dir / f"img_{name}" / frame_name(frame, image_ext)
            out.write_bytes(encode_image(enhance(rgb), image_ext, jpeg_quality))
        (seq_dir / "masks" / frame_name(frame, "png")).write_bytes(encode_mask(truth.motion_mask))
        labels = yolo_lines(truth, cam.width, cam.height, label_min_pixels)
        (seq_dir / "labels" / frame_name(frame, "txt")).write_text("".join(line + "\n" for line in labels))
        for r in truth.rows:
            (static_lines if r.static else moving_lines).append(mot_line(frame, r))
            records.append(
                {
                    "frame": frame,
                    "id": r.id,
                    "class_id": r.class_id,
                    "static": r.static,
                    "w": r.w,
                    "h": r.h,
                    "visibility": r.visibility,
                    "visible_px": r.visible_px,
                    "occluded_px": r.occluded_px,
                    "labelled": r.visible_px >= label_min_pixels,
                }
            )
        if progress is not None:
            progress(1)
    (seq_dir / "gt" / "gt.txt").write_text("".join(line + "\n" for line in moving_lines))
    (seq_dir / "gt" / "static.txt").write_text("".join(line + "\n" for line in static_lines))
    _write_seqinfo(plan, seq_dir, fps=fps, image_ext=image_ext)
    return records


def _write_seqinfo(plan: ScenePlan, seq_dir: Path, *, fps: float, image_ext: str) -> None:
    info = ConfigParser()
    info.optionxform = str  # keep MOTChallenge's key capitalisation
    info["Sequence"] = {
        "name": plan.name,
        "imDir": "img",
        "frameRate": f"{fps:g}",
        "seqLength": str(plan.num_frames),
        "imWidth": str(plan.camera.width),
        "imHeight": str(plan.camera.height),
        "imExt": f".{image_ext}",
        "scenario": plan.scenario,
        "seed": ",".join(str(s) for s in plan.seed),
        "focalPx": f"{plan.camera.focal_px:.3f}",
        "numTargets": str(len(plan.moving)),
        "numStatic": str(len(plan.static)),
        "slewPxPerFrame": f"{plan.slew[0]:.4f},{plan.slew[1]:.4f}",
    }
    with open(seq_dir / "seqinfo.ini", "w") as fh:
        info.write(fh)
