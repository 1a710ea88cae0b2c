"""Score a study's trained detectors on the same sequences labelled another way.

Each piece of a study (`run.py`'s `<study>/results/<variant>_fold<k>.json`) is scored again, with the
best weights of its own MLflow run, on the validation sequences of its fold in another dataset that
holds the same sequences (same names, seeds and folds; the images may be the same and only the labels
differ, as when the ground truth's definition changes). The scores go to
`<study>/on_<dataset>/results/` with `results.json` and `results.md` beside them, in `run.py`'s format,
so the two tables compare row by row, and `labels_<trained on>.json` says how the two datasets' labels
differ (per scenario, every frame: boxes hidden or moved below IoU 0.5, `experiments/seen_truth/run.py`). A dataset whose sequences or folds differ is refused: a
detector would be scored on sequences it trained on.

    python experiments/detector_cv/score_on.py --study finetune_lr --data space_default_psf
"""

from __future__ import annotations

import argparse
import importlib.util
import json
from pathlib import Path

from spacetrack.data.layout import load_manifest
from spacetrack.io import atomic_write_text
from spacetrack.mlflow_log import artifact_file, tracking_uri

HERE = Path(__file__).resolve().parent


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


cv = _load("detector_cv_run", HERE / "run.py")
seen_truth = _load("seen_truth_run", HERE.parent / "seen_truth" / "run.py")


def sequences_and_folds(root: Path) -> dict[str, tuple]:
    """{sequence: (scenario, seed, fold)} of the dataset at `root`."""
    return {s["name"]: (s["scenario"], tuple(s["seed"]), s["fold"]) for s in load_manifest(root)["sequences"]}


def check_same_sequences(trained_on: Path, scored_on: Path) -> None:
    """Refuse `scored_on` unless it holds the sequences of `trained_on` in the same folds."""
    a, b = sequences_and_folds(trained_on), sequences_and_folds(scored_on)
    if a != b:
        differ = sorted(name for name in a.keys() | b.keys() if a.get(name) != b.get(name))
        raise SystemExit(
            f"{scored_on}: its sequences or folds differ from {trained_on}'s ({len(differ)} differ, e.g. "
            f"{differ[:3]}): a detector would be scored on sequences it trained on"
        )


def trained_dataset(piece: dict) -> str:
    """The dataset a piece's detector was trained and scored on: its last `data.name=` override."""
    names = [o.split("=", 1)[1] for o in piece["overrides"] if o.startswith("data.name=")]
    return names[-1] if names else "space_default"


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--study", required=True, help="folder of the study beside this file")
    parser.add_argument("--data", required=True, help="dataset under data/ to score on")
    parser.add_argument(
        "--variants", default="yolov5s,dwt_hsv_gam", help="comma-separated: " + ", ".join(cv.VARIANTS)
    )
    parser.add_argument("--folds", type=int, nargs="+", default=list(range(9)))
    parser.add_argument("--frame-stride", type=int, default=2, help="every n-th validation frame, as run.py")
    args = parser.parse_args()
    study = HERE / args.study
    out = study / f"on_{args.data}"
    (out / "results").mkdir(parents=True, exist_ok=True)
    uri = tracking_uri()
    checked: set[Path] = set()  # datasets the pieces were trained on, compared with args.data once each
    for fold in args.folds:
        for slug in args.variants.split(","):
            source = study / "results" / f"{slug}_fold{fold}.json"
            target = out / "results" / source.name
            if not source.is_file():
                continue
            piece = json.loads(source.read_text())
            cfg = cv.variant_config(slug, fold, [*piece["overrides"], f"data.name={args.data}"], study)
            root = Path(cfg.data_root)
            before, after = root / trained_dataset(piece), root / args.data
            if before not in checked:
                check_same_sequences(before, after)
                labels = out / f"labels_{before.name}.json"
                if not labels.is_file():  # how the labels differ, every frame
                    changes = seen_truth.truth_changes(before, after)
                    atomic_write_text(labels, json.dumps(changes, indent=2) + "\n")
                checked.add(before)
            if target.is_file():
                continue
            weights = artifact_file(piece["run_id"], "weights/best.pt", tracking_uri=uri)
            scores = cv.score(cfg, weights, args.frame_stride)
            keep = {k: piece[k] for k in ("slug", "variant", "fold", "overrides", "run_id", "best_epoch")}
            atomic_write_text(target, json.dumps({**keep, "scored_on": args.data, **scores}, indent=2) + "\n")
            cv.write_tables(out)
            print(f"{target}: mAP@0.5 {scores['all']['map50']:.3f} (was {piece['all']['map50']:.3f})")


if __name__ == "__main__":
    main()
