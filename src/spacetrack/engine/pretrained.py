"""Starting a detector from pretrained weights: the project's own, made by `make pretrain`.

`weights/yolov5s_pretrained.pt` and `weights/yolov5s_gam_pretrained.pt` are detector files as
`spacetrack.export_weights` writes them (`arch` and fp16 `ema` weights). A fine-tuning run loads the one
made for its architecture. Weights with another class count still load: the head's output layers are
left as initialised, and a log line says so. Weights of another architecture are an error, unless
`partial` asks for every tensor whose name and shape match (a GAM model started from plain YOLOv5s).
A model with a stride-4 level (`p2`) loads the three-level file of its kind as it is: the extra level
comes last in the head, so everything else matches, and the new level keeps its initialisation.
"""

from __future__ import annotations

from pathlib import Path

import torch

from spacetrack.config import REPO_ROOT
from spacetrack.engine.checkpoint import differences, load_checkpoint, peek_checkpoint
from spacetrack.models.yolo import YOLOv5

# The shipped pretrained file of each GAM position (None: plain YOLOv5s).
PRETRAINED = {
    None: REPO_ROOT / "weights" / "yolov5s_pretrained.pt",
    "after_sppf": REPO_ROOT / "weights" / "yolov5s_gam_pretrained.pt",
}
HEAD_PREFIX = "detect.m."
# What a stride-4 level adds to the arch of the three-level network it extends.
P2_KEYS = ("p2", "anchors")


def _adds_p2(found: dict, mine: dict) -> bool:
    """Whether the model is the file's three-level network with a stride-4 level added."""
    return bool(mine.get("p2")) and not found.get("p2")


def _architecture_changes(found: dict, mine: dict) -> str:
    """The arch keys that differ between a file and a model (class count aside); a model with a stride-4
    level started from a file without one counts only what differs besides that level."""
    ignore = ("num_classes",) + (P2_KEYS if _adds_p2(found, mine) else ())
    return differences(found, mine, ignore=ignore)


def pretrained_file(gam_position: str | None, p2: bool = False) -> Path | None:
    """The pretrained file of a model with this GAM position (None when it has no file name), with a
    stride-4 level `_p2` before `_pretrained` (`yolov5s_p2_pretrained.pt`, what `spacetrack.pretrain`
    writes for such a model)."""
    path = PRETRAINED.get(gam_position)
    if path is None or not p2:
        return path
    return path.with_name(path.name.replace("_pretrained", "_p2_pretrained"))


def pretrained_files(arch: dict) -> list[Path]:
    """The files `auto` may start a model of this arch from, the first that exists and fits winning: for
    a model with a stride-4 level first the one made for that level, then that of its GAM position."""
    kinds = (True, False) if arch.get("p2") else (False,)
    files = (pretrained_file(arch["gam_position"], p2) for p2 in kinds)
    return [path for path in files if path is not None]


def resolve_weights(choice: str | None, arch: dict) -> Path | None:
    """The weights file a training starts from: `auto` is the shipped pretrained file made for `arch`
    (None when there is none, or when the model is another architecture, a narrower one say), `none`/None
    trains from scratch, anything else is a path."""
    if choice is None or str(choice).lower() == "none":
        return None
    if str(choice) == "auto":
        for path in pretrained_files(arch):
            if path.is_file() and not _architecture_changes(peek_checkpoint(path).get("arch", {}), arch):
                return path
        return None
    path = Path(choice)
    if not path.is_file():
        raise FileNotFoundError(f"pretrained weights {path} not found (weights=none trains from scratch)")
    return path


def load_pretrained(model: YOLOv5, path: str | Path, *, partial: bool = False) -> str:
    """Copy the EMA weights of the detector file at `path` into `model`; return what was loaded, in words.

    The architecture must match except for the class count (the head is then re-initialised); with
    `partial`, every tensor whose name and shape match is loaded and the rest keep their initialisation.
    """
    state = load_checkpoint(path)
    found, mine = dict(state["arch"]), dict(model.arch)
    changed = _architecture_changes(found, mine)
    if changed and not partial:
        raise ValueError(
            f"pretrained weights {path} are of another architecture ({changed}); use weights made for "
            "this model, weights=none to train from scratch, or weights_partial=true to load what matches"
        )
    own = model.state_dict()
    weights = {k: v for k, v in state["ema"].items() if k in own and own[k].shape == v.shape}
    if found["num_classes"] != mine["num_classes"]:
        weights = {k: v for k, v in weights.items() if not k.startswith(HEAD_PREFIX)}
    with torch.no_grad():
        for key, value in weights.items():
            own[key].copy_(value.to(own[key].dtype))
    notes = [f"loaded {len(weights)} of {len(own)} tensors from {path}"]
    if found["num_classes"] != mine["num_classes"]:
        notes.append(
            f"the head was re-initialised: the weights have {found['num_classes']} classes, "
            f"the dataset {mine['num_classes']}"
        )
    if _adds_p2(found, mine):
        notes.append("the stride-4 level is new: it starts from its initialisation")
    if changed:
        notes.append(f"architecture differs ({changed}): the rest keeps its initialisation")
    return "; ".join(notes)
