"""Fusion settings compared on a tuning set rendered apart from the evaluation set (another seed).

    python -m spacetrack.build_data data.name=motion_tune \\
        'data/scenario=[nominal,dim,strong_light,occlusion,multi_target,static_distractors,slew]' \\
        data.num_sequences=7 data.num_folds=7 seed=7 logger=none
    python experiments/table3_motion/tune_fusion.py data/motion_tune

Each variant is `conf/motion/fusion.yaml` with a few keys changed, run beside ViBe and KNN on every
sequence; writes `tuning.md` here (pixel F1 / lit F1 per scenario and pooled, lit precision and recall).
The settings in `conf/motion/` were chosen on this set, so `make eval-motion` (seed 0) scores them on
sequences they were not chosen on.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from hydra.utils import instantiate
from omegaconf import OmegaConf

from spacetrack.config import compose_config
from spacetrack.data.layout import load_manifest
from spacetrack.io import atomic_write_text
from spacetrack.motion.evaluation import MotionScore
from spacetrack.motion.scoring import score_sequence

HERE = Path(__file__).resolve().parent
# name -> (what changes, keys of conf/motion/fusion.yaml to override)
VARIANTS: dict[str, tuple[str, dict]] = {
    "fusion": ("as configured", {}),
    "whole": ("regions kept whole (no hull cut)", {"hull_margin": None}),
    "hull6": ("hull cut grown by 6 px", {"hull_margin": 6}),
    "cut_all": ("hull cut however sparse the difference", {"hull_min_fill": 0.0}),
    "thin": ("3 px filters instead of 5", {"blur_ksize": 3, "close_ksize": 3, "final_ksize": 3}),
    "level160": ("re-binarise at 160 (shrinks masks)", {"blur_level": 160}),
    "radius8": ("ViBe radius 8", {"background": {"radius": 8}}),
    "absorb30": ("ViBe absorbs after 30 frames", {"background": {"absorb_after": 30}}),
    "absorb_fast": ("absorbed pixels update every 4th frame", {"background": {"absorb_subsampling": 4}}),
}  # fmt: skip
PEERS = ("vibe", "knn")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--out", type=Path, default=HERE / "tuning.md")
    args = parser.parse_args()
    cfg = compose_config("eval_motion", ["logger=none", f"dataset={args.dataset}"])
    manifest = load_manifest(args.dataset)
    methods = {name: OmegaConf.to_container(cfg.methods[name], resolve=True) for name in PEERS}
    methods.update(
        {
            name: OmegaConf.to_container(OmegaConf.merge(cfg.methods.fusion, changes), resolve=True)
            for name, (_, changes) in VARIANTS.items()
        }
    )
    rows: dict[str, dict[str, MotionScore]] = {}
    for seq in manifest["sequences"]:
        detectors = {name: instantiate(method) for name, method in methods.items()}
        scores, _ = score_sequence(cfg, args.dataset / seq["name"], detectors, 0.5)
        row = rows.setdefault(seq["scenario"], {})
        for name, score in scores.items():
            row[name] = row.get(name, MotionScore()).merge(score)
        print(seq["name"], {n: round(s.summary()["lit_f1"], 3) for n, s in scores.items()}, flush=True)
    pooled = {name: MotionScore() for name in methods}
    for row in rows.values():
        for name, score in row.items():
            pooled[name] = pooled[name].merge(score)
    rows["overall"] = pooled
    atomic_write_text(args.out, report(rows, list(methods), manifest))
    print(f"wrote {args.out}")


def report(rows: dict[str, dict[str, MotionScore]], methods: list[str], manifest: dict) -> str:
    lines = [
        f"# Fusion settings on the tuning set `{manifest['name']}` (content hash "
        f"`{str(manifest.get('content_hash'))[:19]}…`)",
        "",
        "Written by `tune_fusion.py`. Cells: pixel F1 / lit F1 (truth pixels darker than the "
        "`dark_level` of `conf/eval_motion.yaml` left out); the last table gives lit precision / recall.",
        "",
        "| variant | what changes |",
        "|---|---|",
        *[f"| {name} | {what} |" for name, (what, _) in VARIANTS.items()],
        "",
    ]
    for title, keys in (
        ("F1", ("pixel_f1", "lit_f1")),
        ("lit precision / recall", ("lit_precision", "lit_recall")),
    ):
        lines += [
            f"## {title}",
            "",
            "| scenario | " + " | ".join(methods) + " |",
            "|" + "---|" * (len(methods) + 1),
        ]
        for label, row in rows.items():
            cells = []
            for name in methods:
                summary = row[name].summary()
                cells.append(" / ".join(f"{summary[k]:.3f}" for k in keys))
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
