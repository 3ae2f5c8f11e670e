"""``colonlight.device.resolve_device``: ``auto`` picks what exists, an absent or malformed device fails loudly."""

from __future__ import annotations

import pytest
import torch

from colonlight.device import resolve_device
from colonlight.errors import DeviceError


def test_cpu_and_auto() -> None:
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device(" CPU ") == torch.device("cpu")
    expected = torch.device("cuda:0") if torch.cuda.is_available() else torch.device("cpu")
    assert resolve_device("auto") == resolve_device("") == expected


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("tpu", "unknown device 'tpu': choose auto, cpu, cuda or cuda:N"),
        ("cuda:x", "device 'cuda:x': expected cuda or cuda:N with N a number"),
    ],
)
def test_malformed_devices(spec: str, message: str) -> None:
    with pytest.raises(DeviceError) as err:
        resolve_device(spec)
    assert str(err.value) == message


def test_absent_gpu_is_a_one_line_error() -> None:
    count = torch.cuda.device_count() if torch.cuda.is_available() else 0
    with pytest.raises(DeviceError) as err:
        resolve_device(f"cuda:{count}")
    if count == 0:
        assert "has no CUDA GPU (use --device cpu)" in str(err.value)
    else:
        assert f"only {count} CUDA GPU(s) exist" in str(err.value)
    assert "\n" not in str(err.value)
