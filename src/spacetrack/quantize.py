"""INT8 static quantisation of an exported detector graph by ONNX Runtime, cached like the float export.

    path = quantized_onnx(float_path, calibration_inputs, Calibration(), described={...})

The float graph (`onnx_backend.onnx_session`'s export of `YOLOv5.predict`) is quantised in the QDQ format:
weights per output channel (int8), activations per tensor (uint8), their ranges from the network inputs
of calibration frames (`Calibration.method`). Only the network's own layers are quantised (the nodes the
exporter names `/module/...`); the box decoding after the head stays float32, since 8 bits over a
640-pixel range would move a box by up to 2.5 pixels. `Calibration.head=False` also keeps the head's
1x1 convolutions float.

A quantised file is cached beside the float export as `<float name>-int8-<key>.onnx`, the key covering
the float graph's name (itself a content key of the weights), the calibration settings and frames, and
ONNX Runtime's version; it is written atomically, and the same description is stored in the file's
metadata and checked when the file is opened: a file made from other weights or other settings is
quantised again.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
from collections.abc import Iterator, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from spacetrack.io import atomic_path
from spacetrack.onnx_backend import INPUT_NAME, import_onnxruntime

log = logging.getLogger(__name__)

METHODS = ("minmax", "entropy", "percentile")
NETWORK_PREFIX = "/module/"  # the exporter's names for the nodes of the wrapped network's layers
HEAD_PREFIX = "/module/detect/"
METADATA_KEY = "spacetrack.int8"
CHUNK_FRAMES = 4  # calibration frames whose activations are held at once (about 1.2 GB at 640x640)


@dataclass(frozen=True)
class Calibration:
    """How a graph is quantised.

    frames: calibration frames, spread evenly over the calibration sequences.
    method: how activation ranges are set from them: "minmax" (the default: the extremes seen, reduced
        in the graph, a few seconds; on fold 3 it lost 0.005 mAP@0.5 against float32, experiments/int8/),
        "percentile" (the 99.999th percentile of |x| from histograms: 0.003 lost in one pass over the 64
        frames, but the histograms take minutes to collect, 4 frames at a time to bound the memory) or
        "entropy" (the range keeping most information, histograms too). The histogram methods fail on
        degenerate (e.g. untrained) networks whose channels are constant.
    per_channel: one weight scale per output channel (else one per tensor).
    head: quantise the head's 1x1 convolutions too (their outputs are the scores' logits).
    """

    frames: int = 64
    method: str = "minmax"
    per_channel: bool = True
    head: bool = True

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"calibration method must be one of {METHODS}, got {self.method!r}")
        if not isinstance(self.frames, int) or self.frames < 1:
            raise ValueError(f"calibration frames must be a positive integer, got {self.frames!r}")


class _Reader:
    """ONNX Runtime's CalibrationDataReader protocol over a sequence of network inputs, with the
    `__len__` and `set_range` its strided calibration asks for (so that histograms are collected a few
    frames at a time: at once, 64 frames at 640x640 hold about 19 GB of activations)."""

    def __init__(self, inputs: Sequence[np.ndarray]) -> None:
        self.inputs = inputs
        self.start, self.end, self._next = 0, len(inputs), 0

    def __len__(self) -> int:
        return len(self.inputs)

    def set_range(self, start_index: int, end_index: int) -> None:
        self.start, self.end = start_index, min(end_index, len(self.inputs))
        self._next = self.start

    def get_next(self) -> dict[str, np.ndarray] | None:
        if self._next >= self.end:
            return None
        x = self.inputs[self._next]
        self._next += 1
        return {INPUT_NAME: np.ascontiguousarray(x, dtype=np.float32)}

    def rewind(self) -> None:
        self._next = self.start


def chunk_size(count: int, most: int = CHUNK_FRAMES) -> int:
    """The largest divisor of `count` up to `most`: frames per calibration chunk (ORT wants equal ones)."""
    return max(d for d in range(1, min(most, count) + 1) if count % d == 0)


def description(float_path: Path, calibration: Calibration, described: dict) -> dict:
    """Everything a quantised file depends on: the float graph (named by its weights' content key), the
    settings, the calibration data (`described`: dataset, sequences, enhancement...) and ORT's version."""
    ort = import_onnxruntime()
    return {
        "float_graph": float_path.name,
        "calibration": asdict(calibration) | {"chunk_frames": CHUNK_FRAMES},
        "data": described,
        "onnxruntime": ".".join(ort.__version__.split(".")[:2]),
    }


def description_key(desc: dict) -> str:
    return hashlib.sha256(json.dumps(desc, sort_keys=True).encode()).hexdigest()[:16]


def quantized_path(float_path: Path, desc: dict) -> Path:
    return float_path.with_name(f"{float_path.stem}-int8-{description_key(desc)}.onnx")


def stored_description(path: Path) -> dict | None:
    """The description stored in a quantised file, or None when it has none or is not a readable model."""
    import onnx

    try:
        model = onnx.load(str(path), load_external_data=False)
    except Exception as err:  # a truncated or foreign file: quantised again by the caller
        log.warning("quantised model %s is unreadable (%s)", path, err)
        return None
    for prop in model.metadata_props:
        if prop.key == METADATA_KEY:
            try:
                return json.loads(prop.value)
            except json.JSONDecodeError:
                return None
    return None


def network_nodes(model, *, head: bool) -> list[str]:
    """Names of the nodes to quantise: the network's layers (and the head's convolutions with `head`)."""
    names = [
        n.name
        for n in model.graph.node
        if n.name.startswith(NETWORK_PREFIX) and (head or not n.name.startswith(HEAD_PREFIX))
    ]
    if not names:
        raise ValueError(
            f"no node of the graph is named {NETWORK_PREFIX}...: it was not exported by "
            "onnx_backend.onnx_session from a MethodModule, and which nodes decode boxes is unknown"
        )
    return names


class _DropQuantizerNotes(logging.Filter):
    """ONNX Runtime's quantizer logs advice to the root logger on every call (pre-processing, float
    biases it leaves float); this drops those records, nothing else."""

    def filter(self, record: logging.LogRecord) -> bool:
        return "onnxruntime" not in record.pathname or "quantization" not in record.pathname


@contextlib.contextmanager
def _quiet_quantizer() -> Iterator[None]:
    root = logging.getLogger()
    note = _DropQuantizerNotes()
    handlers = [*root.handlers, logging.lastResort] if logging.lastResort else list(root.handlers)
    root.addFilter(note)
    for handler in handlers:
        handler.addFilter(note)
    try:
        yield
    finally:
        root.removeFilter(note)
        for handler in handlers:
            handler.removeFilter(note)


def quantize(float_path: Path, out_path: Path, inputs: Sequence[np.ndarray], calibration: Calibration,
             desc: dict) -> Path:  # fmt: skip
    """Quantise `float_path` into `out_path` (atomically), `desc` stored in its metadata."""
    import onnx
    from onnxruntime.quantization import CalibrationMethod, QuantFormat, QuantType, quantize_static

    model = onnx.load(str(float_path))
    nodes = network_nodes(model, head=calibration.head)
    method = {"minmax": CalibrationMethod.MinMax, "entropy": CalibrationMethod.Entropy,
              "percentile": CalibrationMethod.Percentile}[calibration.method]  # fmt: skip
    with atomic_path(out_path) as tmp, _quiet_quantizer():
        quantize_static(
            model,
            str(tmp),
            _Reader(inputs),
            quant_format=QuantFormat.QDQ,
            per_channel=calibration.per_channel,
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            nodes_to_quantize=nodes,
            calibrate_method=method,
            extra_options={"CalibMovingAverage": False, "CalibStridedMinMax": chunk_size(len(inputs))},
        )
        quantized = onnx.load(str(tmp))
        entry = quantized.metadata_props.add()
        entry.key, entry.value = METADATA_KEY, json.dumps(desc, sort_keys=True)
        onnx.save(quantized, str(tmp))
    return out_path


def quantized_onnx(
    float_path: str | Path,
    inputs: Sequence[np.ndarray],
    calibration: Calibration,
    described: dict,
) -> Path:
    """The INT8 graph of the float graph at `float_path`, from the cache beside it or quantised there
    now. inputs: the calibration frames as network inputs (1, 3, H, W) float32 in [0, 1], a sequence that
    may prepare each on access; described: what those frames are (enters the cache key)."""
    float_path = Path(float_path)
    desc = description(float_path, calibration, described)
    path = quantized_path(float_path, desc)
    if path.is_file():
        if stored_description(path) == desc:
            return path
        log.warning("quantised model %s was made from another graph or settings: quantising again", path)
    log.info("quantising %s to INT8 on %d calibration frames (%s)", float_path.name, calibration.frames,
             calibration.method)  # fmt: skip
    return quantize(float_path, path, inputs, calibration, desc)


def training_frames(
    weights: str | Path, count: int, data: str | Path | None = None
) -> tuple[list[np.ndarray], dict]:
    """`count` RGB frames the detector at `weights` was trained on, spread evenly over its training
    sequences, enhanced as it was trained (its checkpoint's `settings`), and what they are.

    data: the dataset folder (None: `data/<the checkpoint's dataset>` in the repository). The sequences are
    every one outside the checkpoint's validation fold (all of them when the checkpoint names no fold
    or the dataset has no such fold), so that a held-out fold scores a model calibrated without it.
    """
    from hydra.utils import instantiate

    from spacetrack.config import REPO_ROOT
    from spacetrack.data.layout import frame_paths, load_manifest, read_rgb
    from spacetrack.engine.checkpoint import load_checkpoint

    settings = load_checkpoint(weights).get("settings") or {}
    if data is None:
        name = (settings.get("data") or {}).get("name")
        if not name:
            raise ValueError(
                f"{weights} records no training dataset: give the INT8 backend its calibration frames "
                "with calibration_data=<dataset folder>"
            )
        data = REPO_ROOT / "data" / name
    root = Path(data)
    manifest = load_manifest(root)
    fold = settings.get("fold")
    names = [s["name"] for s in manifest["sequences"] if s["fold"] != fold]
    if not names:
        raise ValueError(f"dataset {root} has no sequence outside fold {fold} to calibrate {weights} on")
    paths = [p for seq in names for p in frame_paths(root, seq)]
    chosen = [paths[i] for i in np.unique(np.linspace(0, len(paths) - 1, count).round().astype(int))]
    enhance = settings.get("enhance") or {"_target_": "spacetrack.enhance.NoEnhancement"}
    enhancer = instantiate(enhance)
    frames = [enhancer(read_rgb(p)) for p in chosen]
    described = {"dataset": manifest.get("name", root.name), "held_out_fold": fold,
                 "sequences": names, "frames": [str(p.relative_to(root)) for p in chosen],
                 "enhance": enhance}  # fmt: skip
    return frames, described
