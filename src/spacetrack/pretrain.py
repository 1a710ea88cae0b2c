"""Pretrain the detector on its own dataset and ship the weights: `python -m spacetrack.pretrain`.

YOLOv5 users fine-tune from pretrained weights; these are made here, on `data/space_pretrain`, a dataset
rendered with another seed than the cross-validation data, so that no fold's sequences are ever seen
before that fold is held out. The training is `spacetrack.train`'s with `conf/pretrain.yaml`; its best
EMA weights go to `weights/yolov5s_pretrained.pt` (or `yolov5s_gam_pretrained.pt`) in fp16, with the
resolved settings inside the file. A stopped run resumes where its last checkpoint left it.
`torchrun --nproc_per_node=N -m spacetrack.pretrain` trains on N GPUs as `spacetrack.train` does.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import DictConfig

from spacetrack import cli
from spacetrack.data.layout import load_manifest
from spacetrack.engine.distributed import launched_world
from spacetrack.engine.pretrained import PRETRAINED, pretrained_file
from spacetrack.export_weights import export_detector
from spacetrack.train import fit


def seed_key(seed: int | list[int]) -> tuple[int, ...]:
    """A sequence's render seed (an integer or the builder's [dataset seed, index] list) as a tuple."""
    return tuple(seed) if isinstance(seed, (list, tuple)) else (int(seed),)


def shared_sequences(pretrain: dict, cv: dict) -> list[str]:
    """Names of the sequences of manifest `pretrain` that manifest `cv` also holds: rendered from the same
    seed (the same scene), or, by name and scenario, from the same dataset content."""
    cv_seeds = {seed_key(s["seed"]) for s in cv["sequences"]}
    same = [s["name"] for s in pretrain["sequences"] if seed_key(s["seed"]) in cv_seeds]
    if pretrain.get("content_hash") and pretrain.get("content_hash") == cv.get("content_hash"):
        same = [s["name"] for s in pretrain["sequences"]]
    return same


def check_disjoint(pretrain_root: Path, cv_root: Path) -> None:
    """Refuse a pretraining dataset that shares a sequence with the cross-validation dataset."""
    pretrain = load_manifest(pretrain_root)
    if Path(pretrain_root).resolve() == Path(cv_root).resolve():
        raise ValueError(f"the pretraining dataset {pretrain_root} is the cross-validation dataset itself")
    if not (Path(cv_root) / "manifest.json").is_file():
        print(f"pretrain: {cv_root} is not built yet; nothing to compare {pretrain_root} with")
        return
    shared = shared_sequences(pretrain, load_manifest(cv_root))
    if shared:
        raise ValueError(
            f"the pretraining dataset {pretrain_root} shares {len(shared)} sequences with the "
            f"cross-validation dataset {cv_root} (same render seeds, e.g. {shared[0]}): pretraining on "
            "them would leak the folds. Render it with another seed: "
            "python -m spacetrack.build_data data=pretrain seed=1000 overwrite=true"
        )


def check_rendered(root: Path, num_sequences: int) -> None:
    """Refuse a pretraining dataset rendered with another sequence count than its config asks for (an
    older `data/space_pretrain`): the weights would record settings they were not made with."""
    found = len(load_manifest(root)["sequences"])
    if found != num_sequences:
        raise ValueError(
            f"the pretraining dataset {root} holds {found} sequences, its config (data.num_sequences) asks "
            f"for {num_sequences}: render it again with python -m spacetrack.build_data data=pretrain "
            "seed=1000 overwrite=true"
        )


def run(cfg: DictConfig) -> dict[str, float]:
    """Pretrain one model; write its fp16 weights to `cfg.export_dir`; return the best epoch's metrics."""
    root = Path(cfg.data_root) / cfg.data.name
    check_rendered(root, int(cfg.data.num_sequences))
    check_disjoint(root, Path(cfg.cv_data))
    result = fit(cfg)
    if not launched_world().is_main:  # one of several processes that trained together: rank 0 exports
        return result["metrics"]
    gam = cfg.model.gam_position
    shipped = pretrained_file(gam, bool(cfg.model.get("p2")))
    if shipped is None:
        raise ValueError(f"no pretrained file name for gam_position {gam!r} (known: {list(PRETRAINED)})")
    folder = Path(cfg.export_dir)
    folder.mkdir(parents=True, exist_ok=True)
    written = export_detector(result["best"], folder / shipped.name)
    print(f"pretrain: wrote {written} ({written.stat().st_size / 1e6:.1f} MB) from {result['best']}")
    return result["metrics"]


@cli.entry_point("pretrain", metric="fitness", files="export_dir")
def main(cfg: DictConfig) -> float:
    return run(cfg)["fitness"]


if __name__ == "__main__":
    main()
