"""Mixed precision: which autocast type a forward pass runs in on this device."""

from __future__ import annotations

import torch


def native_bfloat16() -> bool:
    """Whether this CPU computes bfloat16 natively (AVX-512 BF16 or AMX, as oneDNN reports it); elsewhere
    bfloat16 is emulated and slower than float32."""
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):
        return False


def autocast_dtype(device: torch.device, amp: bool) -> torch.dtype | None:
    """What mixed precision runs the forward pass in: float16 on CUDA, bfloat16 on a CPU that has it
    natively, None (float32) on other CPUs or with `amp` off."""
    if not amp:
        return None
    if device.type == "cuda":
        return torch.float16
    return torch.bfloat16 if device.type == "cpu" and native_bfloat16() else None
