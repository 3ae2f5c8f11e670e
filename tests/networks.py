"""Networks for tests: a given head with a random output layer, so that its outputs move from frame to frame."""

from __future__ import annotations

from pathlib import Path

import torch

from colonlight.checkpoint import LoadedWeights
from colonlight.model import GammaNet


def random_head_weights(head: str, path: Path, sha256: str, size: int = 32, inputs: str = "rgb") -> LoadedWeights:
    """``head``'s network (seed 2) with its output weights drawn from N(0, 0.5), away from the identity start; the
    gamma head also gets a bias of 1 (a around 1: a usable gamma rather than the ReLU's floor) and the paper's two
    seed frames."""
    torch.manual_seed(2)
    net = GammaNet(head=head, inputs=inputs).eval()
    with torch.no_grad():
        net.out_linear.weight.normal_(0.0, 0.5)
        if head == "gamma":
            net.out_linear.bias.fill_(1.0)
    seeds = 2 if head == "gamma" else 0
    return LoadedWeights(net=net, name=head, sha256=sha256, path=path, card={"input_size": size, "seed_frames": seeds})
