"""Shared fixtures: paths to the authors' reference fixture (skipped where ../shared is absent), a tiny model."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(os.environ.get("COLONLIGHT_SHARED", REPO.parent / "shared"))
REFERENCE = SHARED / "fixtures" / "colonlight-reference"
AUTHORS_CKPT = REFERENCE / "gamma_thru10_first2prev2_ssimALL_Epoch6.pth"


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
