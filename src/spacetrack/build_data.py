"""Render a dataset of space-scene sequences with exact ground truth (`make data`).

    python -m spacetrack.build_data                                   # data/space_default
    python -m spacetrack.build_data data=smoke seed=3                 # data/space_smoke
    python -m spacetrack.build_data 'data/scenario=[dim,occlusion]' data.name=dim_occ data.num_sequences=18
    python -m spacetrack.build_data enhance=dwt_hsv overwrite=true    # also writes img_dwt_hsv/

The dataset is built in a temporary folder beside its destination and renamed into place only when every
sequence, the manifest and the card are written.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterator
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict
from pathlib import Path

import mlflow
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from spacetrack import cli
from spacetrack.config import resolved_dict
from spacetrack.data import card
from spacetrack.data.folds import assign_folds
from spacetrack.data.geometry import CLASS_NAMES
from spacetrack.data.layout import FORMAT_VERSION, MANIFEST
from spacetrack.data.raster import Camera
from spacetrack.data.render import SequenceRenderer, check_truth, longest_hidden_run
from spacetrack.data.scenario import ScenarioParams, scenario_params
from spacetrack.data.scene import ScenePlan, plan_sequence
from spacetrack.data.writer import write_sequence
from spacetrack.io import atomic_dir
from spacetrack.mlflow_log import start_run

MAX_PLAN_TRIES = 40


def check_config(cfg: DictConfig) -> None:
    """Reject impossible settings before any work, naming the key and the value."""
    d = cfg.data
    if not (32 <= d.width <= 8192 and 32 <= d.height <= 8192):
        raise ValueError(
            f"data.width x data.height = {d.width}x{d.height}: each must be within 32..8192 pixels"
        )
    if d.num_frames < 5:
        raise ValueError(f"data.num_frames={d.num_frames}: at least 5 frames are needed")
    if d.num_folds < 2:
        raise ValueError(f"data.num_folds={d.num_folds}: at least 2 folds are needed")
    if d.num_sequences < d.num_folds:
        raise ValueError(f"data.num_sequences={d.num_sequences} is less than data.num_folds={d.num_folds}")
    if d.image_ext not in ("jpg", "png"):
        raise ValueError(f"data.image_ext={d.image_ext!r}: expected 'jpg' or 'png'")
    if not d.get("scenario"):
        raise ValueError("no scenario selected: choose some with 'data/scenario=[nominal,dim]'")
    check_truth(d.truth, d.seen_snr, prefix="data.")
    if not 0 < d.hfov_deg < 170:
        raise ValueError(f"data.hfov_deg={d.hfov_deg}: expected a field of view in (0, 170) degrees")
    root = Path(cfg.dataset_dir).parent
    if not root.is_dir():
        raise FileNotFoundError(
            f"output folder {root} does not exist (dataset_dir={cfg.dataset_dir}); create it first"
        )


def scenario_table(cfg: DictConfig) -> dict[str, ScenarioParams]:
    table = {name: scenario_params(name, node) for name, node in cfg.data.scenario.items()}
    for name, params in table.items():
        if params.occlusion_pair and cfg.data.num_frames < 40:
            raise ValueError(
                f"scenario {name!r} needs data.num_frames >= 40 to hide a target for "
                f"{params.hidden_frames_min} frames and show it again (got {cfg.data.num_frames})"
            )
    return table


def sequence_specs(cfg: DictConfig, scenarios: list[str]) -> list[dict]:
    """Name, scenario, seed and fold of every sequence; scenarios are dealt in turn."""
    names = [scenarios[i % len(scenarios)] for i in range(cfg.data.num_sequences)]
    folds = assign_folds(names, cfg.data.num_folds, cfg.seed)
    return [
        {"name": f"seq_{i:03d}_{s}", "scenario": s, "seed": [int(cfg.seed), i], "fold": folds[i]}
        for i, s in enumerate(names)
    ]


def make_plan(spec: dict, params: ScenarioParams, camera: Camera, num_frames: int) -> ScenePlan:
    """Plan a sequence; for an occlusion set-up, redraw until the far target is hidden long enough."""
    for attempt in range(MAX_PLAN_TRIES):
        seed = spec["seed"] if attempt == 0 else [*spec["seed"], attempt]
        plan = plan_sequence(
            name=spec["name"],
            scenario=spec["scenario"],
            params=params,
            camera=camera,
            num_frames=num_frames,
            seed=seed,
        )
        if not params.occlusion_pair:
            return plan
        hidden, seen_after = longest_hidden_run(SequenceRenderer(plan), obj_id=2)
        if hidden >= params.hidden_frames_min and seen_after:
            return plan
    raise RuntimeError(
        f"{spec['name']}: no occlusion of >= {params.hidden_frames_min} frames in {MAX_PLAN_TRIES} tries; "
        "use a larger image or more frames"
    )


def render_one(
    spec: dict, params: dict, data_cfg: dict, enhance_cfg: dict, out_root: str
) -> tuple[dict, list[dict]]:
    """Worker: plan, render and write one sequence; returns its manifest entry and truth records."""
    camera = Camera.from_fov(data_cfg["width"], data_cfg["height"], data_cfg["hfov_deg"])
    plan = make_plan(spec, ScenarioParams(**params), camera, data_cfg["num_frames"])
    enhancer = instantiate(enhance_cfg)
    enhancers = [] if enhancer.name == "none" else [(enhancer.name, enhancer)]
    records = write_sequence(
        plan,
        Path(out_root) / spec["name"],
        fps=data_cfg["fps"],
        image_ext=data_cfg["image_ext"],
        jpeg_quality=data_cfg["jpeg_quality"],
        label_min_pixels=data_cfg["label_min_pixels"],
        enhancers=enhancers,
        truth=data_cfg["truth"],
        seen_snr=data_cfg["seen_snr"],
    )
    entry = {
        **spec,
        "seed": plan.seed,
        "num_frames": plan.num_frames,
        "width": camera.width,
        "height": camera.height,
        "fps": data_cfg["fps"],
        "num_targets": len(plan.moving),
        "num_static": len(plan.static),
    }
    for r in records:
        r["sequence"] = spec["name"]
    return entry, records


def _render_all(jobs: list[tuple], workers: int) -> Iterator[tuple[dict, list[dict]]]:
    """Results of `render_one` as sequences finish; a failure cancels the sequences not yet started."""
    if workers <= 1:
        yield from (render_one(*job) for job in jobs)
        return
    pool = ProcessPoolExecutor(max_workers=workers)
    try:
        for future in as_completed([pool.submit(render_one, *job) for job in jobs]):
            yield future.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def content_hash(root: Path) -> str:
    """sha256 over every file's relative path and bytes in sorted order, leaving out the manifest and the
    card (which quote the hash)."""
    digest = hashlib.sha256()
    for path in sorted(p for p in root.rglob("*") if p.is_file() and p.name not in (MANIFEST, "CARD.md")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes())
    return "sha256:" + digest.hexdigest()


def run(cfg: DictConfig) -> dict[str, float]:
    check_config(cfg)
    table = scenario_table(cfg)
    specs = sequence_specs(cfg, list(table))
    data_cfg = OmegaConf.to_container(cfg.data, resolve=True)
    enhance_cfg = OmegaConf.to_container(cfg.enhance, resolve=True)
    enhance_name = instantiate(cfg.enhance).name
    out_dir = Path(cfg.dataset_dir)
    entries, records = {}, []
    with atomic_dir(out_dir, overwrite=cfg.overwrite) as tmp:
        jobs = [(s, asdict(table[s["scenario"]]), data_cfg, enhance_cfg, str(tmp)) for s in specs]
        bar = tqdm(
            total=len(specs) * cfg.data.num_frames, unit="frame", disable=not cfg.progress, desc=out_dir.name
        )
        for entry, recs in _render_all(jobs, cfg.workers):
            entries[entry["name"]] = entry
            records.extend(recs)
            bar.update(entry["num_frames"])
        bar.close()
        sequences = [entries[s["name"]] for s in specs]
        records.sort(key=lambda r: (r["sequence"], r["frame"], r["id"]))
        stats = card.statistics(records, sequences, list(CLASS_NAMES))
        card.plot_distributions(records, tmp / "card_stats.png")
        card.write_contact_sheet(tmp, sequences, cfg.data.image_ext, tmp / "contact_sheet.jpg")
        manifest = {
            "name": cfg.data.name,
            "format_version": FORMAT_VERSION,
            "class_names": list(CLASS_NAMES),
            "num_folds": cfg.data.num_folds,
            "image_ext": cfg.data.image_ext,
            "image_dirs": ["img"] + ([f"img_{enhance_name}"] if enhance_name != "none" else []),
            "width": cfg.data.width,
            "height": cfg.data.height,
            "fps": cfg.data.fps,
            "sequences": sequences,
            "counts": stats,
            "config": resolved_dict(cfg),
        }
        manifest["content_hash"] = content_hash(tmp)
        (tmp / "CARD.md").write_text(card.card_markdown(manifest, stats))
        (tmp / MANIFEST).write_text(json.dumps(manifest, indent=2) + "\n")
    with start_run(cfg, run_name=cfg.data.name) as active:
        if active is not None:
            mlflow.log_metrics({k: float(v) for k, v in stats.items() if isinstance(v, (int, float))})
            for name in ("CARD.md", "card_stats.png", "contact_sheet.jpg", MANIFEST):
                mlflow.log_artifact(str(out_dir / name))
    return {k: float(v) for k, v in stats.items() if isinstance(v, (int, float))}


@cli.entry_point("build_data", files="dataset_dir")
def main(cfg: DictConfig) -> dict[str, float]:
    stats = run(cfg)
    return {k: stats[k] for k in ("sequences", "frames", "moving_targets", "static_objects")}


if __name__ == "__main__":
    main()
