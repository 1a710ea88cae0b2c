"""Table 4: MOTA and HOTA per fold for each tracking setting, resumable per (row, fold).

    python experiments/table4_mota/run.py                         # every row, every fold
    python experiments/table4_mota/run.py --rows gt_sort,gt_sort_nofilter --folds 0-8
    python experiments/table4_mota/run.py --rows gt_peers --folds 3 threads=1   # BoxMOT's trackers (make peers)

Each finished (row, fold) writes `results/<row>/fold<k>.json` (its metrics overall and per sequence, the
overrides and the command), then `table4.md` and `table4.json` are regenerated from every result
present, so a killed run loses at most the piece it was on. It writes files and commits nothing. `--rows`
takes row names and the groups of `GROUPS` (`peers`: every BoxMOT row; `gt_peers`: those on
ground-truth boxes). A piece whose fold has no trained detector or re-ID is skipped with the command that
trains it; run again once it exists. With `--train` the missing model is trained there and then (that
same command, plus the `--detector-args` or `--reid-args` overrides) and the piece runs after it: one
command fills whole folds, and being killed loses little: finished training runs are in MLflow and found
the next time, and a training stopped part-way goes on from its last epoch (`resume=auto` for the
detector and the re-ID). A piece already done is recomputed only when it is stale: when the
settings that change its numbers (`settings_hash`: data, enhancement, detector, re-ID, tracker, motion
stage, dynamic filter, scoring) differ from those it was made with; `--redo` recomputes the pieces asked
for anyway (after a change of code rather than of settings). Stale cells are starred in `table4.md`.

    python experiments/table4_mota/run.py --folds 1 --train threads=1 \
        --detector-args "train.threads=1" --reid-args "train_reid.threads=1"
"""

from __future__ import annotations

import argparse
import functools
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from spacetrack.config import REPO_ROOT, compose_config, resolved_dict
from spacetrack.data.layout import load_manifest, read_mot, split_sequences
from spacetrack.evaluation import evaluate
from spacetrack.evaluation.mot import scored_rows
from spacetrack.io import atomic_write_text
from spacetrack.pipeline.cache import config_hash
from spacetrack.pipeline.runner import filter_mode
from spacetrack.pipeline.weights import MissingWeightsError

HERE = Path(__file__).resolve().parent
RESULTS = HERE / "results"
GT = ["detector=ground_truth"]
# YOLOv5's own NMS (per class, no part suppression), as the paper's detector has it
PER_CLASS_NMS = ["detector.agnostic_nms=false", "detector.part_overlap=null"]
YOLO = ["detector=yolo", "detector_run.gam_position=none", "enhance=none"] + PER_CLASS_NMS
GAM = ["detector=yolo", "detector_run.gam_position=after_sppf", "enhance=dwt_hsv"] + PER_CLASS_NMS
# The paper's pipeline: the per-frame filter, no camera motion in the tracker.
PAPER = ["tracker.camera_motion=false", "tracker.output_box=state"]
# DeepSORT's two matching stages (no re-acquisition), its output rule and its Kalman update
REFERENCE_MATCHING = [
    "tracker.reacquire_gate=null",
    "tracker.coast_in_view=false",
    "tracker.occluded_area=null",
    "tracker.low_confidence=null",
]
NOFILTER = ["dynamic_filter=false"] + PAPER
PAPER_FILTER = ["dynamic_filter=frame", "dynamic_hold.frames=0"] + PAPER  # the paper's per-frame filter
HOLD = ["dynamic_filter=frame", "dynamic_hold.frames=30"] + PAPER
TRACK = [
    "dynamic_filter=track",
    "tracker.camera_motion=auto",
    "tracker.output_box=detection",
]  # beyond the paper: conf/track.yaml's default
# No fold's own re-ID network is in this checkout's MLflow store: the ground-truth DeepSORT rows use the
# shipped one (trained with fold 3 held out; on the other folds it has seen the identities).
SHIPPED_REID = ["reid.weights=weights/reid_fold3.pt"]
# Beyond the paper and never live: conf/track.yaml's offline post-processing (tracking.offline) after each
# sequence; its rows say OFFLINE and stand apart from the online ones.
OFFLINE = ["offline.enabled=true"]
# row name -> (what the paper's Table 4 calls it, overrides of conf/track.yaml)
ROWS: dict[str, tuple[str, list[str]]] = {
    "yolo_deepsort_original": ("original DeepSORT settings, plain YOLOv5s", YOLO + ["tracker=deepsort_original"] + PAPER_FILTER + REFERENCE_MATCHING),
    "yolo_deepsort_paper": ("paper settings (Table 2), plain YOLOv5s", YOLO + ["tracker=deepsort_paper"] + PAPER_FILTER + REFERENCE_MATCHING),
    "gam_deepsort_paper": ("paper settings, YOLOv5s + GAM + DWT/HSV (the paper's method)", GAM + ["tracker=deepsort_paper"] + PAPER_FILTER + REFERENCE_MATCHING),
    "gam_deepsort_original": ("original DeepSORT settings, YOLOv5s + GAM + DWT/HSV", GAM + ["tracker=deepsort_original"] + PAPER_FILTER + REFERENCE_MATCHING),
    "gam_deepsort_paper_hold": ("the paper's method, filter with a 30-frame hold (beyond the paper)", GAM + ["tracker=deepsort_paper"] + HOLD + REFERENCE_MATCHING),
    "yolo_deepsort_paper_objectness": ("paper settings, plain YOLOv5s, each box scored by its objectness (beyond the paper)", YOLO + ["tracker=deepsort_paper", "detector.score=objectness"] + PAPER_FILTER + REFERENCE_MATCHING),
    "gam_deepsort_paper_objectness": ("the paper's method, each box scored by its objectness (beyond the paper)", GAM + ["tracker=deepsort_paper", "detector.score=objectness"] + PAPER_FILTER + REFERENCE_MATCHING),
    "yolo_deepsort_paper_nofilter": ("paper settings, plain YOLOv5s, no dynamic-target filter", YOLO + ["tracker=deepsort_paper"] + NOFILTER + REFERENCE_MATCHING),
    "yolo_sort": ("SORT (IoU only), plain YOLOv5s: the floor", YOLO + ["tracker=sort", "reid.weights=none"] + PAPER_FILTER),
    "gt_deepsort_original": ("ground-truth boxes, original DeepSORT settings, track-level decision (online)", GT + ["tracker=deepsort_original"] + TRACK + SHIPPED_REID),
    "gt_deepsort_paper": ("ground-truth boxes, paper settings, track-level decision (online)", GT + ["tracker=deepsort_paper"] + TRACK + SHIPPED_REID),
    "gt_deepsort_original_frame": ("ground-truth boxes, original DeepSORT settings, the paper's per-frame filter", GT + ["tracker=deepsort_original"] + PAPER_FILTER + REFERENCE_MATCHING + SHIPPED_REID),
    "gt_deepsort_paper_frame": ("ground-truth boxes, paper settings, the paper's per-frame filter", GT + ["tracker=deepsort_paper"] + PAPER_FILTER + REFERENCE_MATCHING + SHIPPED_REID),
    "gt_deepsort_paper_nofilter": ("ground-truth boxes, paper settings, no filter", GT + ["tracker=deepsort_paper"] + NOFILTER + REFERENCE_MATCHING + SHIPPED_REID),
    "gt_sort": ("ground-truth boxes, SORT", GT + ["tracker=sort", "reid.weights=none"] + PAPER_FILTER),
    "gt_sort_hold": ("ground-truth boxes, SORT, filter with a 30-frame hold (beyond the paper)", GT + ["tracker=sort", "reid.weights=none"] + HOLD),
    "gt_sort_nofilter": ("ground-truth boxes, SORT, no dynamic-target filter", GT + ["tracker=sort", "reid.weights=none"] + NOFILTER),
    "gt_sort_track": ("ground-truth boxes, SORT, track-level decision (online)", GT + ["tracker=sort", "reid.weights=none"] + TRACK),
    "gt_deepsort_original_nonms": ("ground-truth boxes, original DeepSORT settings with NMS off (1.0, as the paper's), track-level decision (online)", GT + ["tracker=deepsort_original", "tracker.nms_max_overlap=1.0"] + TRACK + SHIPPED_REID),
    "gt_deepsort_original_offline": ("ground-truth boxes, original DeepSORT settings, track-level decision, OFFLINE: backfill + gap interpolation (beyond the paper)", GT + ["tracker=deepsort_original"] + TRACK + OFFLINE + SHIPPED_REID),
    "gt_deepsort_paper_offline": ("ground-truth boxes, paper settings, track-level decision, OFFLINE: backfill + gap interpolation (beyond the paper)", GT + ["tracker=deepsort_paper"] + TRACK + OFFLINE + SHIPPED_REID),
    "gam_deepsort_original_offline": ("original DeepSORT settings, YOLOv5s + GAM + DWT/HSV, OFFLINE: backfill + gap interpolation (beyond the paper)", GAM + ["tracker=deepsort_original"] + PAPER_FILTER + REFERENCE_MATCHING + OFFLINE),
}  # fmt: skip
# BoxMOT's trackers (`make peers`) with BoxMOT's default settings, in the pipeline of the DeepSORT rows they
# stand beside: on ground-truth boxes that of `gt_deepsort_original` (track-level decision, our camera shift
# for its evidence, the matched detection's box), on a detector that of `yolo_deepsort_original`. The peers
# that match by appearance get our re-ID features; ByteTrack and OC-SORT take none.
PEERS = {"bytetrack": "ByteTrack", "ocsort": "OC-SORT", "botsort": "BoT-SORT (its camera-motion compensation)",
         "strongsort": "StrongSORT", "deepocsort": "Deep OC-SORT"}  # fmt: skip
APPEARANCE = {"botsort", "strongsort", "deepocsort"}


def _peer_rows(
    prefix: str, where: str, base: list[str], pipeline: list[str], reid: list[str], *, own_cache: bool
) -> dict:
    """The peer rows on one kind of boxes. own_cache: the peers that take no appearance run with no re-ID
    network (a cache of their own); else they read the detections the DeepSORT rows cached, whose
    features they ignore (a detector row then costs no second pass of the detector)."""
    no_reid = ["reid.weights=none"] if own_cache else reid
    return {
        f"{prefix}_{peer}": (
            f"{where}, BoxMOT {name}, its defaults",
            base + [f"tracker={peer}"] + pipeline + (reid if peer in APPEARANCE else no_reid),
        )
        for peer, name in PEERS.items()
    }


ROWS |= _peer_rows("gt", "ground-truth boxes", GT, TRACK, SHIPPED_REID, own_cache=True)
ROWS |= _peer_rows("yolo", "plain YOLOv5s", YOLO, PAPER_FILTER, [], own_cache=False)
ROWS |= _peer_rows("gam", "YOLOv5s + GAM + DWT/HSV", GAM, PAPER_FILTER, [], own_cache=False)
GROUPS = {
    "peers": [r for r in ROWS if r.split("_", 1)[1] in PEERS],
    "gt_peers": [f"gt_{peer}" for peer in PEERS],
}
SHOWN = ("mota", "hota", "deta", "assa", "idf1", "motp", "idsw", "fp", "fn")
# The parts of conf/track.yaml that change a piece's numbers, and keys within them that change only speed.
RESULT_KEYS = ("data", "enhance", "detector", "detector_run", "reid", "reid_run", "reid_min_score", "tracker", "motion",
               "dynamic", "dynamic_hold", "dynamic_filter", "dynamic_track", "offline", "iou_threshold",
               "min_visibility", "max_frames")  # fmt: skip
SPEED_ONLY = frozenset({"device", "threads", "onnx_dir", "parallel", "batch_size"})


def folds_arg(text: str) -> list[int]:
    """'0-8' or '1,3,5' -> fold indices."""
    if "-" in text:
        a, b = text.split("-")
        return list(range(int(a), int(b) + 1))
    return [int(v) for v in text.split(",")]


def piece_overrides(row: str, fold: int, common: list[str]) -> list[str]:
    """conf/track.yaml overrides that track fold `fold` with row `row`'s settings."""
    return (
        ROWS[row][1]
        + common
        + [
            f"fold={fold}",
            f"output_dir=outputs/table4/{row}/fold{fold}",
            "video=false",
            "progress=false",
            "logger.experiment=table4_mota",
        ]
    )


def settings_hash(overrides: list[str]) -> str:
    """Hash of what in the track config with `overrides` changes the numbers: not the fold (a piece's
    own), nor where it writes, nor the keys that change only speed."""
    cfg = compose_config("track", overrides)

    def strip(value: object) -> object:
        if isinstance(value, dict):
            return {k: strip(v) for k, v in value.items() if k not in SPEED_ONLY}
        return value

    def section(key: str) -> object:
        value = OmegaConf.select(cfg, key)
        return strip(resolved_dict(value)) if isinstance(value, DictConfig) else value

    return config_hash(_without_unused({key: section(key) for key in RESULT_KEYS}))


def _without_unused(settings: dict) -> dict:
    """`settings` less the options that do not act in its mode, each at the value that gives the numbers
    of before the option existed, so the pieces made then keep their hash."""
    mode = filter_mode(settings["dynamic_filter"])
    settings["dynamic_filter"] = {"frame": True, "off": False}.get(mode, mode)
    if not (mode == "frame" and settings["dynamic_hold"]["frames"]):
        del settings["dynamic_hold"]  # no hold (or no filter to hold)
    if mode != "track":
        del settings["dynamic_track"]
    if not settings["offline"]["enabled"]:
        del settings["offline"]  # online
    # a tracker without an appearance metric (SORT) never reads the features
    if "max_cosine_distance" in settings["tracker"] and settings["tracker"]["max_cosine_distance"] is None:
        settings["reid"]["weights"] = "none"
    # the re-ID settings were one block when the first pieces were made
    settings["reid"] = {k: v for k, v in settings["reid"].items() if k != "_target_"}
    settings["reid"] |= {
        "experiment": settings.pop("reid_run")["experiment"],
        "min_score": settings.pop("reid_min_score"),
    }
    # the run's GAM position was selected by the key `model` when the first pieces were made
    settings["detector_run"] = {
        "model" if k == "gam_position" else k: v for k, v in settings["detector_run"].items()
    }
    if settings["detector_run"].get("p2") is False:
        del settings["detector_run"]["p2"]  # every run's detector had three levels before
    if settings["detector"].get("score") == "class":
        del settings["detector"]["score"]  # a detection's score was always objectness x class before
    if settings["detector"].get("agnostic_nms") is False:
        del settings["detector"]["agnostic_nms"]  # and NMS per class
    if "part_overlap" in settings["detector"] and settings["detector"]["part_overlap"] is None:
        del settings["detector"]["part_overlap"]  # with no part suppression
    before_options = (("camera_motion", False), ("output_box", "state"), ("reacquire_gate", None),
                      ("coast_in_view", False), ("occluded_area", None), ("low_confidence", None),
                      ("motion_rescue", False))  # fmt: skip
    for key, before in before_options:
        if key in settings["tracker"] and settings["tracker"][key] == before:
            del settings["tracker"][key]
    # boxes that all score at least min_confidence (ground truth's) leave no low-scored one to match
    score = settings["detector"].get("score")  # a number for ground truth, a kind of score for a network
    if isinstance(score, int | float) and score >= settings["tracker"].get("min_confidence", 1.0):
        settings["tracker"].pop("low_confidence", None)
    return settings


def run_piece(row: str, fold: int, common: list[str]) -> dict:
    """Track fold `fold` with row `row`'s settings; the metrics and what made them."""
    from spacetrack import track

    overrides = piece_overrides(row, fold, common)
    started = time.time()
    cfg = compose_config("track", overrides)
    metrics = track.run(cfg)
    return {
        "row": row,
        "fold": fold,
        "metrics": metrics,
        "sequences": sequence_scores(cfg),
        "settings": settings_hash(overrides),
        "code": _git("rev-parse", "--short", "HEAD"),
        # code and settings files that differed from that commit when the piece ran
        "changed": _git("diff", "--name-only", "HEAD", "--", "src", "conf").split(),
        "overrides": overrides,
        "command": "python -m spacetrack.track " + " ".join(overrides),
        "seconds": time.time() - started,
        "profile": "GPU"
        if torch.cuda.is_available()
        else f"CPU ({platform.processor() or platform.machine()})",
    }


def sequence_scores(cfg: DictConfig) -> dict[str, dict]:
    """{sequence: its scenario, counted ground-truth boxes and `SHOWN` metrics} of the fold `cfg` tracked,
    scored again from the MOT files the piece wrote (`track.run` returns the fold's pooled scores)."""
    root = Path(cfg.dataset)
    manifest = load_manifest(root)
    scenario = {s["name"]: s["scenario"] for s in manifest["sequences"]}
    scoring = {"iou_threshold": cfg.iou_threshold, "min_visibility": cfg.min_visibility}
    out = {}
    for name in split_sequences(manifest, cfg.fold)[1]:
        gt, hyp = read_mot(root / name / "gt" / "gt.txt"), read_mot(Path(cfg.output_dir) / f"{name}.txt")
        if cfg.max_frames:
            gt = gt[gt[:, 0] <= cfg.max_frames]
        metrics = evaluate({name: (gt, hyp)}, **scoring)[name]
        counted = int(scored_rows(gt, hyp, **scoring)[0].sum())
        out[name] = {"scenario": scenario[name], "gt_boxes": counted} | {m: metrics[m] for m in SHOWN}
    return out


# How each training module picks up a run that was stopped part-way (a no-op when there is none).
RESUME = {"spacetrack.train": ["resume=auto"], "spacetrack.train_reid": ["resume=auto"]}


def run_with_models(row: str, fold: int, common: list[str], train_args: dict[str, list[str]] | None) -> dict:
    """`run_piece`; with `train_args` ({training module: extra overrides}) each missing model is first
    trained by the command its error names plus that module's extra overrides. Without, a missing model
    raises MissingWeightsError."""
    trained: list[tuple] = []
    while True:
        try:
            return run_piece(row, fold, common)
        except MissingWeightsError as err:
            if train_args is None or err.train is None:
                raise
            module, overrides = err.train
            if (module, overrides) in trained:
                raise RuntimeError(
                    f"{module} {' '.join(overrides)} finished, but its run is still not found: {err}"
                ) from err
            trained.append((module, overrides))
            resume = RESUME.get(module, [])
            command = [sys.executable, "-m", module, *overrides, *resume, *train_args.get(module, [])]
            print("training: " + " ".join(command[1:]), flush=True)
            subprocess.run(command, cwd=REPO_ROOT, check=True)


def _git(*args: str) -> str:
    done = subprocess.run(["git", "-C", str(REPO_ROOT), *args], capture_output=True, text=True)
    return done.stdout.strip()


def load_results() -> dict[str, dict[int, dict]]:
    out: dict[str, dict[int, dict]] = {}
    for path in sorted(RESULTS.glob("*/fold*.json")):
        record = json.loads(path.read_text())
        out.setdefault(record["row"], {})[int(record["fold"])] = record
    return out


def _command_template(record: dict) -> str:
    k = record["fold"]
    return record["command"].replace(f"fold={k}", "fold=K").replace(f"/fold{k}", "/foldK")


def current_settings(common: list[str]) -> dict[str, str]:
    """{row: `settings_hash` of its pieces under the current config with `common` overrides}."""
    return dict(_current_settings(tuple(common)))


@functools.lru_cache(maxsize=16)
def _current_settings(common: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    # one config composition per row (about 30 of them) per process and set of overrides
    return tuple((row, settings_hash(piece_overrides(row, 0, list(common)))) for row in ROWS)


def _mean(done: dict[int, dict], metric: str) -> float | None:
    """Mean of `metric` over the folds whose record has it (those made before HOTA have none)."""
    values = [d["metrics"][metric] for d in done.values() if metric in d["metrics"]]
    return float(np.mean(values)) if values else None


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{100 * value:.1f}"


def scenario_scores(done: dict[int, dict]) -> dict[str, dict[str, float]]:
    """{scenario: pooled MOTA, HOTA, IDF1 and the sequence count} over the folds' per-sequence scores.

    MOTA pools exactly (1 - the summed FN + FP + IDSW over the summed counted ground-truth boxes); HOTA
    and IDF1 are the sequences' values weighted by their counted boxes."""
    out: dict[str, dict[str, float]] = {}
    sequences = [s for d in done.values() for s in d.get("sequences", {}).values()]
    for scenario in sorted({s["scenario"] for s in sequences}):
        part = [s for s in sequences if s["scenario"] == scenario]
        boxes = sum(s["gt_boxes"] for s in part)
        errors = sum(s["fn"] + s["fp"] + s["idsw"] for s in part)
        out[scenario] = {
            "mota": 1 - errors / boxes if boxes else float("nan"),
            **{m: sum(s[m] * s["gt_boxes"] for s in part) / boxes if boxes else float("nan") for m in ("hota", "idf1")},
            "sequences": len(part),
        }  # fmt: skip
    return out


def _fold_table(results: dict, stale: set, metric: str, num_folds: int, tail: list[str]) -> list[str]:
    """A markdown table of `metric` per fold for each row with a result that has it, then `tail` columns."""
    lines = [
        "| row | " + " | ".join(f"fold {k}" for k in range(num_folds)) + " | mean ± std | " + " | ".join(tail) + " |",
        "|---|" + "---|" * (num_folds + 1 + len(tail)),
    ]  # fmt: skip
    for row, (title, _) in ROWS.items():
        done = {k: d for k, d in results.get(row, {}).items() if metric in d["metrics"]}
        if not done:
            continue
        values = [done[k]["metrics"][metric] for k in sorted(done)]
        cells = [
            _pct(done[k]["metrics"][metric]) + ("*" if (row, k) in stale else "") if k in done else "-"
            for k in range(num_folds)
        ]
        full = results[row]
        extra = {
            "MOTA mean": _pct(_mean(full, "mota")), "HOTA mean": _pct(_mean(full, "hota")),
            "DetA mean": _pct(_mean(full, "deta")), "AssA mean": _pct(_mean(full, "assa")),
            "IDF1 mean": _pct(_mean(full, "idf1")),
            **{m.upper(): f"{sum(d['metrics'][m] for d in full.values()):.0f}" for m in ("idsw", "fp", "fn")},
        }  # fmt: skip
        folds = f"{len(values)} fold" + ("s" if len(values) != 1 else "")
        lines.append(
            f"| `{row}`: {title} | " + " | ".join(cells)
            + f" | {100 * np.mean(values):.1f} ± {100 * np.std(values):.1f} ({folds}) | "
            + " | ".join(extra[c] for c in tail) + " |"
        )  # fmt: skip
    return lines


def _scenario_table(summary: dict) -> list[str]:
    rows = {row: s["scenarios"] for row, s in summary.items() if s["scenarios"]}
    scenarios = sorted({name for per in rows.values() for name in per})
    if not rows:
        return []
    lines = [
        "## MOTA / HOTA per scenario",
        "",
        "Pooled over the folds each row has per-sequence scores for (MOTA exactly, HOTA weighted by the",
        "sequences' ground-truth boxes); in %.",
        "",
        "| row | " + " | ".join(scenarios) + " | folds |",
        "|---|" + "---|" * (len(scenarios) + 1),
    ]
    for row, per in rows.items():
        cells = [f"{_pct(per[n]['mota'])} / {_pct(per[n]['hota'])}" if n in per else "-" for n in scenarios]
        lines.append(f"| `{row}` | " + " | ".join(cells) + f" | {summary[row]['scenario_folds']} |")
    return lines


def piece_common(row: str, record: dict) -> list[str]:
    """The overrides a piece was run with beyond its row's own and its fold's: the runner's common ones."""
    # the row's own keys, and `detector_run.model`, the name of `detector_run.gam_position` before
    own = {o.split("=", 1)[0] for o in ROWS.get(row, ("", []))[1]} | {"detector_run.model"}
    per_fold = {"fold", "output_dir", "video", "progress", "logger.experiment"}
    return [o for o in record.get("overrides", []) if o.split("=", 1)[0] not in own | per_fold]


def write_tables(num_folds: int = 9, current: dict[str, str] | None = None) -> list[Path]:
    """table4.md and table4.json from every result present; returns their paths. A cell made with other
    settings than `current`, or by default than the current config gives with the common overrides
    that piece was run with (`piece_common`), is starred."""
    results = load_results()

    def now(row: str, record: dict) -> str | None:
        table = current if current is not None else current_settings(piece_common(row, record))
        return table.get(row)

    stale = {
        (row, k) for row, done in results.items() for k, r in done.items() if r.get("settings") != now(row, r)
    }
    summary = {}
    for row, (title, _) in ROWS.items():
        done = results.get(row, {})
        if not done:
            continue
        mota = [done[k]["metrics"]["mota"] for k in sorted(done)]
        first = next(iter(done.values()))
        summary[row] = {
            "title": title,
            "folds": {k: {m: done[k]["metrics"].get(m) for m in SHOWN} for k in sorted(done)},
            "mota_mean": float(np.mean(mota)),
            "mota_std": float(np.std(mota)),
            **{f"{m}_mean": _mean(done, m) for m in ("hota", "deta", "assa", "idf1")},
            **{m: sum(d["metrics"][m] for d in done.values()) for m in ("idsw", "fp", "fn")},
            "scenarios": scenario_scores(done),
            "scenario_folds": sum("sequences" in d for d in done.values()),
            "command": _command_template(first),
            "profile": first["profile"],
        }
    lines = [
        "# Table 4: MOTA and HOTA per validation fold",
        "",
        "Regenerate with `make table4` (= `python experiments/table4_mota/run.py`; `make table4 ROWS=peers`",
        "for BoxMOT's trackers); each cell is one fold's sequences tracked with that fold's own models (never",
        "trained on them). `-`: not run yet. What each row's models were, and why some cells are missing, is",
        "in README.md.",
        "",
        "## MOTA",
        "",
        *_fold_table(results, stale, "mota", num_folds, ["HOTA mean", "IDF1 mean", "IDSW", "FP", "FN"]),
        "",
        "MOTA, HOTA and IDF1 in %; IDSW, FP and FN summed over the folds shown. HOTA mean: over the folds",
        "whose piece was made since HOTA is scored (TrackEval; `-`: none yet).",
        "",
        "## HOTA",
        "",
        *_fold_table(results, stale, "hota", num_folds, ["DetA mean", "AssA mean", "MOTA mean"]),
        "",
        *_scenario_table(summary),
    ]
    if stale:
        lines += [
            "",
            f"*: {len(stale)} cells were made with other settings than the current config; "
            "`python experiments/table4_mota/run.py` recomputes them.",
        ]
    lines += ["", "Commands per row:", ""]
    lines += [f"- `{row}`: `{s['command']}` ({s['profile']})" for row, s in summary.items()]
    md, js = HERE / "table4.md", HERE / "table4.json"
    atomic_write_text(md, "\n".join(lines) + "\n")
    atomic_write_text(js, json.dumps(summary, indent=2) + "\n")
    return [md, js]


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--rows", default=",".join(ROWS), help=f"comma-separated rows or groups {list(GROUPS)} (default: all)"
    )
    parser.add_argument("--folds", default="0-8", help="'0-8' or '1,3'")
    parser.add_argument("--redo", action="store_true", help="recompute pieces already done and current")
    parser.add_argument("--train", action="store_true", help="train a piece's missing models, then run it")
    parser.add_argument("--detector-args", default="", help="extra overrides for detector training")
    parser.add_argument("--reid-args", default="", help="extra overrides for re-ID training")
    parser.add_argument("overrides", nargs="*", help="extra track.yaml overrides for every piece")
    args = parser.parse_args()
    rows = [r for name in args.rows.split(",") for r in GROUPS.get(name, [name])]
    unknown = [r for r in rows if r not in ROWS]
    if unknown:
        parser.error(f"unknown rows {unknown}; known: {list(ROWS)} and the groups {list(GROUPS)}")
    train_args = None
    if args.train:
        train_args = {"spacetrack.train": args.detector_args.split(),
                      "spacetrack.train_reid": args.reid_args.split()}  # fmt: skip
    missing = []
    settings = current_settings(args.overrides)  # composed once, not after every piece
    # a bar over the pieces to compute (the rate and the time left); pieces already current leave its total
    bar = tqdm(total=len(rows) * len(folds_arg(args.folds)), desc="Table 4", unit="piece")
    for row in rows:
        current = settings[row]
        for fold in folds_arg(args.folds):
            path = RESULTS / row / f"fold{fold}.json"
            if path.is_file() and not args.redo:
                made_with = json.loads(path.read_text()).get("settings")
                if made_with == current:
                    bar.total -= 1
                    bar.refresh()
                    continue
                print(
                    f"{row} fold {fold} is stale (settings {made_with} -> {current}): recomputing", flush=True
                )
            try:
                record = run_with_models(row, fold, args.overrides, train_args)
            except MissingWeightsError as err:
                missing.append(f"{row} fold {fold}: {err}")
                print(f"skipped {row} fold {fold}: {err}", flush=True)
                bar.update()
                continue
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_write_text(path, json.dumps(record, indent=2) + "\n")
            write_tables()
            m = record["metrics"]
            print(f"{row} fold {fold}: MOTA {m['mota']:.4f}, HOTA {m['hota']:.4f}", flush=True)
            bar.update()
    bar.close()
    write_tables()
    if missing:
        print(f"{len(missing)} pieces wait for trained models:\n" + "\n".join(missing))


if __name__ == "__main__":
    main()
