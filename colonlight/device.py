"""Compute-device choice: ``auto`` prefers a GPU when one is present; an explicit GPU that is absent fails loudly."""

from __future__ import annotations

import torch

from .errors import DeviceError


def resolve_device(spec: str = "auto") -> torch.device:
    """Turn ``auto | cpu | cuda | cuda:N`` into a ``torch.device``; raise :class:`DeviceError` if it is absent."""
    if spec is not None and not isinstance(spec, str):  # 5 or torch.device(...): not an AttributeError of str's
        raise DeviceError(f"device must be auto, cpu, cuda or cuda:N (text), got {spec!r}")
    spec = (spec or "auto").strip().lower()
    if spec == "auto":
        return torch.device("cuda:0" if torch.cuda.is_available() else "cpu")
    if spec == "cpu":
        return torch.device("cpu")
    if spec == "cuda" or spec.startswith("cuda:"):
        index_text = spec.partition(":")[2] or "0"
        # isdecimal and ASCII: "cuda:²" passed isdigit and failed in int() with a ValueError traceback
        if not (index_text.isascii() and index_text.isdecimal()) or len(index_text) > 6:
            raise DeviceError(f"device {spec!r}: expected cuda or cuda:N with N a number")
        index = int(index_text)
        if not torch.cuda.is_available():
            raise DeviceError(f"device {spec!r} requested, but this machine has no CUDA GPU (use --device cpu)")
        if index >= torch.cuda.device_count():
            raise DeviceError(f"device {spec!r} requested, but only {torch.cuda.device_count()} CUDA GPU(s) exist")
        return torch.device(f"cuda:{index}")
    raise DeviceError(f"unknown device {spec!r}: choose auto, cpu, cuda or cuda:N")
