"""ONNX Runtime inference for the networks: export once to a cached .onnx file, run it on numpy arrays.

    session = onnx_session(net, (1, 3, 128, 64), dynamic_batch=True, threads=1)
    (features,) = session(crops)            # float32 numpy in, a list of float32 numpy outputs

A graph is exported with the TorchScript-based `torch.onnx.export` (it needs the `onnx` package): on a
2-core CPU it writes YOLOv5s in ~3 s where the torch.export-based exporter takes ~30 s, and both graphs
give the same outputs. Exports are cached under `outputs/onnx/` by a content key (architecture, weights,
input shape, opset), so changed weights are exported anew and unchanged ones are not; a cached file
ONNX Runtime cannot read (truncated, damaged) is exported again.
"""

from __future__ import annotations

import hashlib
import logging
import warnings
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from torch import nn

from spacetrack.config import REPO_ROOT
from spacetrack.io import atomic_path

log = logging.getLogger(__name__)

BACKENDS = ("torch", "onnxruntime", "auto")
# The detector has two more: torch under bfloat16 autocast, and the ONNX graph quantised to INT8.
DETECTOR_BACKENDS = ("torch", "torch_bf16", "onnxruntime", "onnxruntime_int8", "auto")
DEFAULT_OPSET = 17
DEFAULT_CACHE_DIR = REPO_ROOT / "outputs" / "onnx"
INPUT_NAME, OUTPUT_NAME = "input", "output"


def check_backend(backend: str, device: str = "cpu", choices: Sequence[str] = BACKENDS) -> str:
    """The backend that runs: `backend`, with "auto" resolved to onnxruntime on the CPU (float32: the
    fastest backend there whose detections are the float network's) and to torch on CUDA (the CPU
    onnxruntime package has no CUDA provider); a ValueError naming `choices` for anything else."""
    if backend not in choices:
        raise ValueError(f"backend must be one of {tuple(choices)}, got {backend!r}")
    if backend == "auto":
        return "onnxruntime" if device == "cpu" else "torch"
    return backend


def import_onnxruntime():
    """The onnxruntime module, or an ImportError that says how to install it."""
    try:
        import onnxruntime
    except ImportError as err:
        raise ImportError(
            "backend onnxruntime needs the onnxruntime and onnx packages, dependencies of spacetrack in "
            "pyproject.toml: run `make install` (or `.venv/bin/pip install -e .`), or use backend=torch"
        ) from err
    return onnxruntime


class MethodModule(nn.Module):
    """`module.<method>` as a module's forward, so that a method other than forward (YOLOv5.predict:
    the network with its box decoding) can be exported."""

    def __init__(self, module: nn.Module, method: str) -> None:
        super().__init__()
        self.module, self.method = module, method

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return getattr(self.module, self.method)(x)


def content_key(module: nn.Module, input_shape: Sequence[int], *, opset: int, dynamic_batch: bool) -> str:
    """16 hex digits naming what an export depends on: the layers (their repr), every parameter and buffer
    (names, shapes, values), the input shape, the batch axis and the opset."""
    digest = hashlib.sha256()
    digest.update(f"{module!r}|{tuple(input_shape)}|opset={opset}|dynamic_batch={dynamic_batch}".encode())
    for name, tensor in module.state_dict().items():
        value = tensor.detach().cpu().contiguous()
        digest.update(f"|{name}:{value.dtype}:{tuple(value.shape)}|".encode())
        digest.update(value.reshape(-1).view(torch.uint8).numpy().tobytes())
    return digest.hexdigest()[:16]


def export_onnx(
    module: nn.Module,
    input_shape: Sequence[int],
    path: str | Path,
    *,
    opset: int = DEFAULT_OPSET,
    dynamic_batch: bool = False,
) -> Path:
    """Write `module` (in eval mode) on a float32 input of `input_shape` to `path` as ONNX, atomically.

    The graph has one input `input` and the module's output `output`; `dynamic_batch` leaves their first
    axis free (the re-ID network runs on any number of crops), else every shape is fixed.
    """
    module = module.eval()
    device = next(module.parameters()).device
    axes = {INPUT_NAME: {0: "batch"}, OUTPUT_NAME: {0: "batch"}} if dynamic_batch else None
    with atomic_path(path) as tmp, torch.no_grad(), warnings.catch_warnings():
        # The TorchScript exporter is chosen on purpose (see the module docstring): its deprecation notices
        # would repeat on every export. Tracing turns the networks' input checks into constants of the
        # graph, which is right for inputs of the exported shape and is what the tracer warns about.
        warnings.filterwarnings("ignore", category=DeprecationWarning)
        warnings.filterwarnings("ignore", category=torch.jit.TracerWarning)
        torch.onnx.export(
            module,
            (torch.zeros(tuple(input_shape), device=device),),
            str(tmp),
            dynamo=False,
            opset_version=opset,
            input_names=[INPUT_NAME],
            output_names=[OUTPUT_NAME],
            dynamic_axes=axes,
        )
    return Path(path)


class OrtSession:
    """An ONNX Runtime session on `path`: `session(x)` -> the graph's outputs as float32 numpy arrays.

    threads: intra-op threads (0: ONNX Runtime's default, one per physical core).
    device: "cpu", or "cuda" for the CUDAExecutionProvider when the installed onnxruntime has it (the
        onnxruntime-gpu package); without it a warning is given and the CPU is used.
    spinning: let the intra-op threads spin between calls (ONNX Runtime's default). Off here: spinning
        threads keep the cores busy after a call returns, and on a 2-core machine the torch stage, the
        motion thread or another process that runs next gets them only when the spinning stops (measured:
        a 2-thread torch forward after a spinning 2-thread session took 605 ms instead of 211 ms, and the
        session itself ran faster without spinning on the loaded machine, 80 against 104 ms).
    """

    def __init__(
        self, path: str | Path, *, threads: int = 0, device: str = "cpu", spinning: bool = False
    ) -> None:
        ort = import_onnxruntime()
        if threads < 0:
            raise ValueError(f"threads must be >= 0 (0: ONNX Runtime's default), got {threads}")
        if device not in ("cpu", "cuda"):
            raise ValueError(f"device must be 'cpu' or 'cuda' for onnxruntime, got {device!r}")
        providers = ["CPUExecutionProvider"]
        if device == "cuda":
            if "CUDAExecutionProvider" in ort.get_available_providers():
                providers.insert(0, "CUDAExecutionProvider")
            else:
                warnings.warn(
                    "onnxruntime has no CUDAExecutionProvider (install onnxruntime-gpu): running on the CPU",
                    stacklevel=2,
                )
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        options.add_session_config_entry("session.intra_op.allow_spinning", "1" if spinning else "0")
        self.path = Path(path)
        self.session = ort.InferenceSession(str(path), options, providers=providers)
        self.providers = self.session.get_providers()

    def __call__(self, x: np.ndarray) -> list[np.ndarray]:
        return self.session.run(None, {INPUT_NAME: np.ascontiguousarray(x, dtype=np.float32)})


def _unreadable_model_errors() -> tuple[type[Exception], ...]:
    """What ONNX Runtime raises on a file that is not a usable model."""
    from onnxruntime.capi import onnxruntime_pybind11_state as state

    return (state.InvalidProtobuf, state.InvalidArgument, state.InvalidGraph, state.Fail)


def onnx_session(
    module: nn.Module,
    input_shape: Sequence[int],
    *,
    threads: int = 0,
    device: str = "cpu",
    dynamic_batch: bool = False,
    opset: int = DEFAULT_OPSET,
    cache_dir: str | Path | None = None,
    name: str = "model",
) -> OrtSession:
    """An OrtSession running `module` on float32 inputs of `input_shape` (any first axis with
    `dynamic_batch`), from `<cache_dir>/<name>-<content key>.onnx`, exported there first when missing or
    unreadable. cache_dir: default `outputs/onnx/` in the repository; created when missing.
    """
    import_onnxruntime()  # before an export that would be of no use
    folder = Path(cache_dir) if cache_dir is not None else DEFAULT_CACHE_DIR
    folder.mkdir(parents=True, exist_ok=True)
    key = content_key(module, input_shape, opset=opset, dynamic_batch=dynamic_batch)
    path = folder / f"{name}-{key}.onnx"
    if path.is_file():
        try:
            return OrtSession(path, threads=threads, device=device)
        except _unreadable_model_errors() as err:
            log.warning("cached ONNX file %s is unreadable (%s): exporting it again", path, err)
    export_onnx(module, input_shape, path, opset=opset, dynamic_batch=dynamic_batch)
    return OrtSession(path, threads=threads, device=device)
