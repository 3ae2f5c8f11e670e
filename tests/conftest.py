"""Shared fixtures: paths to the authors' reference fixture (skipped where ../shared is absent), a tiny model."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("COLONLIGHT_SHARED", REPO.parent / "shared"))
REFERENCE = SHARED / "fixtures" / "colonlight-reference"
AUTHORS_CKPT = REFERENCE / "gamma_thru10_first2prev2_ssimALL_Epoch6.pth"
CPP_HOST_DIR = REPO / "examples" / "cpp_host"
CPP_HOST_BUILD_TIMEOUT_S = 600  # compiling against OpenCV and ONNX Runtime on a loaded 2-core machine


@pytest.fixture(scope="session")
def reference_dir() -> Path:
    """The authors' checkpoint + frames + expected values; skip where ../shared is absent."""
    if not (REFERENCE / "expected.json").is_file() or not AUTHORS_CKPT.is_file():
        pytest.skip(
            f"needs the paper authors' published checkpoint and reference frames, not in this repository "
            f"(unlicensed: https://github.com/zhangybzbo/ColonLight); expected at {REFERENCE} "
            "(../shared beside the checkout, or COLONLIGHT_SHARED)"
        )
    return REFERENCE


@pytest.fixture(scope="session")
def authors_checkpoint(reference_dir: Path) -> Path:
    return reference_dir / AUTHORS_CKPT.name


@pytest.fixture(scope="session")
def random_weights(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A freshly initialised network saved in our format (for tests that need any weights, not good ones)."""
    import torch

    from colonlight.checkpoint import save_weights
    from colonlight.model import GammaNet

    torch.manual_seed(0)
    net = GammaNet().eval()
    with torch.no_grad():  # a positive output bias so that a ~ 1.5: a usable, brightening model
        net.out_linear.bias.fill_(1.5)
    path = tmp_path_factory.mktemp("weights") / "random.safetensors"
    save_weights(net, path, {"name": "random-test", "input_size": 64})
    return path


@pytest.fixture(scope="session")
def cpp_host(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``colonlight_host`` (examples/cpp_host), built once per session by the example's own Makefile (ONNX
    Runtime's headers fetched by it if needed); skipped where g++, make or the OpenCV and nlohmann-json headers
    are missing, or the headers cannot be fetched. A host that does not compile fails the test that asked."""
    import shutil
    import subprocess
    import sys

    if shutil.which("g++") is None or shutil.which("make") is None:
        pytest.skip("no g++ or make on this machine (`make -C examples/cpp_host deps` installs them as root)")
    headers_needed = ("opencv4/opencv2/imgproc.hpp", "nlohmann/json.hpp")
    missing = [h for h in headers_needed if not (Path("/usr/include") / h).is_file()]
    if missing:
        pytest.skip(f"no {', '.join(missing)}: `make -C examples/cpp_host deps` (as root) installs them")
    headers = subprocess.run(["make", "-s", "-C", str(CPP_HOST_DIR), "headers"], capture_output=True, text=True)
    if headers.returncode != 0:
        pytest.skip(f"ONNX Runtime's headers could not be fetched: {headers.stderr.strip().splitlines()[-1:]}")
    build = tmp_path_factory.mktemp("cpp_host")
    system = Path("/usr/include/onnxruntime")
    include = system if system.is_dir() else CPP_HOST_DIR / "build/onnxruntime/include"
    make = ["make", "-C", str(CPP_HOST_DIR), f"BUILD={build}", f"ORT_INCLUDE={include}", f"PYTHON={sys.executable}"]
    result = subprocess.run(make, capture_output=True, text=True, timeout=CPP_HOST_BUILD_TIMEOUT_S)
    assert result.returncode == 0, result.stdout + result.stderr  # a host that does not compile is a defect
    return build / "colonlight_host"
