"""The network's inputs beyond the paper's RGB: ``rgb-log`` (the frame beside its log intensity, in which a gain
change is one shift everywhere), ``rgb-prev`` (the frame beside itself under the last frame's correction) and
``delta`` (the frame under the last correction beside its difference from the last output, the head changing the
last correction), and ``delta-rank`` (``delta`` plus how much the pixels' brightness order changed). Each starts
from an ``rgb`` checkpoint's first convolution and survives saving and loading."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import torch

from colonlight.checkpoint import load_weights, save_weights
from colonlight.correction import apply_head
from colonlight.errors import CheckpointError, OptionError
from colonlight.methods.rnn import RecurrentGammaMethod
from colonlight.model import LOG_FLOOR, RANK_SCALE, GammaNet, log_channels, rank_change
from colonlight.train import TrainConfig, initial_net, model_card

from ...networks import random_head_weights


def test_log_channels_span_the_floor_to_one_and_turn_a_gain_into_one_shift() -> None:
    ends = log_channels(torch.tensor([0.0, LOG_FLOOR, 1.0]))
    assert torch.allclose(ends, torch.tensor([0.0, 0.0, 1.0]), atol=1e-6)
    frame = torch.rand(1, 3, 8, 8) * 0.5 + 0.05
    shift = log_channels(frame * 1.7) - log_channels(frame)
    assert float(shift.std()) < 1e-5 and float(shift.mean()) > 0.05


@pytest.mark.parametrize("inputs", ["rgb-log", "rgb-prev"])
def test_an_rgb_checkpoint_starts_the_network_with_the_same_outputs(inputs: str, tmp_path: Path) -> None:
    torch.manual_seed(0)
    rgb = GammaNet(head="gain-gamma").eval()
    with torch.no_grad():
        rgb.out_linear.weight.normal_(0.0, 0.5)
    path = tmp_path / "rgb.safetensors"
    save_weights(rgb, path, {"name": "rgb", "head": "gain-gamma"})
    net = initial_net(TrainConfig(init=str(path), head="gain-gamma", inputs=inputs, objective="relative")).eval()
    assert net.inputs == inputs and tuple(net.in_cnv.weight.shape[:2]) == (32, 6)
    assert torch.equal(net.in_cnv.weight[:, 3:], torch.zeros_like(net.in_cnv.weight[:, 3:]))
    clip = torch.rand(2, 6, 3, 24, 24)
    with torch.no_grad():
        assert torch.equal(net(clip), rgb(clip))


def test_rgb_log_weights_round_trip_and_a_card_that_disagrees_is_refused(tmp_path: Path) -> None:
    torch.manual_seed(1)
    net = GammaNet(head="gain-gamma", inputs="rgb-log").eval()
    path = tmp_path / "log.safetensors"
    save_weights(net, path, {"name": "log", "head": "gain-gamma", "inputs": "rgb-log"})
    loaded = load_weights(path).net
    assert loaded.inputs == "rgb-log"
    clip = torch.rand(1, 4, 3, 24, 24)
    with torch.no_grad():
        assert torch.equal(loaded(clip), net(clip))
    card_file = path.with_suffix(".json")
    card = json.loads(card_file.read_text())
    card_file.write_text(json.dumps({**card, "inputs": "rgb"}))
    with pytest.raises(CheckpointError, match="inputs 'rgb', the weights read 6 channels"):
        load_weights(path)
    card_file.write_text(json.dumps({k: v for k, v in card.items() if k != "inputs"}))
    with pytest.raises(CheckpointError, match="could be rgb-log or rgb-prev or delta; its model card must say which"):
        load_weights(path)


def test_rgb_prev_sees_the_frame_under_the_last_correction_and_carries_it_in_the_state() -> None:
    torch.manual_seed(3)
    net = GammaNet(head="gain-gamma", inputs="rgb-prev").eval()
    with torch.no_grad():
        net.out_linear.weight.normal_(0.0, 0.5)
        net.in_cnv.weight[:, :3].zero_()  # only the corrected copy reaches the network
    frame = torch.rand(1, 3, 16, 16) * 0.8 + 0.1
    with torch.no_grad():
        z1, state = net.step(frame, None)
        assert len(state) == 3 and torch.equal(state[2], z1)
        z2, _ = net.step(frame, state)
        # the same frame under the same correction, from the same memory: what changes is the last correction
        fresh, _ = net.step(frame, (state[0], state[1], torch.zeros_like(z1)))
    assert not torch.allclose(z2, fresh)
    with pytest.raises(OptionError, match="needs the gain-gamma or curve head"):
        GammaNet(head="gamma", inputs="rgb-prev")


def test_a_delta_network_changes_its_last_correction_and_keeps_it_when_its_output_is_zero() -> None:
    torch.manual_seed(5)
    net = GammaNet(head="gain-gamma", inputs="delta").eval()
    clip = torch.rand(2, 7, 3, 16, 16)
    with torch.no_grad():
        assert torch.equal(net(clip), torch.zeros(2, 7, 2))  # a zero output layer keeps the identity throughout
        net.out_linear.bias.fill_(0.1)  # a constant change: the correction grows by it every frame
        assert torch.allclose(net(clip)[0, :, 0], 0.1 * torch.arange(1, 8).float(), atol=1e-6)
        net.out_linear.weight.normal_(0.0, 0.5)
        net.in_cnv.weight[:, 3:].normal_(0.0, 0.5)
        frame = clip[:, 0]
        z, state = net.step(frame, None)
        assert len(state) == 4 and torch.equal(state[2], z)
        assert torch.allclose(state[3], apply_head(frame, z, "gain-gamma"))
        # the zero state an ONNX host starts from is the same as no state
        zeros = tuple(torch.zeros_like(t) for t in state)
        assert torch.equal(net.step(frame, zeros)[0], z)
        # the difference from the last output is seen: the same frame after another output moves differently
        z2, _ = net.step(frame, state)
        other, _ = net.step(frame, (*state[:3], torch.full_like(state[3], 0.5)))
    assert not torch.allclose(z2, other)
    with pytest.raises(OptionError, match="'delta' needs the gain-gamma or curve head"):
        GammaNet(head="gamma", inputs="delta")


def test_rank_change_is_zero_under_a_lighting_change_and_large_under_a_change_of_scene() -> None:
    torch.manual_seed(6)
    frame = torch.rand(2, 3, 48, 40) * 0.9 + 0.05
    relit = (frame**0.6 * 1.3).clamp_max(0.95)  # a tone curve and a gain: each channel's order kept
    assert torch.allclose(rank_change(frame, relit), torch.zeros(2), atol=1e-6)
    assert torch.allclose(rank_change(frame, 1.0 - frame), torch.full((2,), 2.0), atol=1e-6)
    other = torch.rand(2, 3, 48, 40)
    assert bool((rank_change(frame, other) > 0.8).all())
    # pixels clipped in one frame are ties there: they tell nothing about order, and a flat frame tells nothing
    assert bool(((relit == 0.95).float().mean() > 0.2).item())
    flat = torch.full_like(frame, 0.5)
    assert torch.allclose(rank_change(frame, flat), torch.ones(2), atol=1e-6)
    # a small frame is sampled whole; a large one on a fixed grid, so the cost does not grow with the size
    assert rank_change(frame[:, :, :4, :4], relit[:, :, :4, :4]).shape == (2,)


def test_a_delta_rank_network_starts_as_its_delta_checkpoint_and_reads_the_rank_plane(tmp_path: Path) -> None:
    torch.manual_seed(7)
    delta = GammaNet(head="curve", inputs="delta").eval()
    with torch.no_grad():
        delta.out_linear.weight.normal_(0.0, 0.5)
        delta.in_cnv.weight[:, 3:].normal_(0.0, 0.5)
    path = tmp_path / "delta.safetensors"
    save_weights(delta, path, {"name": "delta", "head": "curve", "inputs": "delta"})
    net = initial_net(TrainConfig(init=str(path), head="curve", inputs="delta-rank", objective="relative")).eval()
    clip = torch.rand(1, 6, 3, 32, 32)
    with torch.no_grad():
        assert torch.equal(net(clip), delta(clip))  # the plane's weights start at zero
        net.in_cnv.weight[:, 6:].normal_(0.0, 0.5)
        frame = clip[:, 0]
        z, state = net.step(frame, None)
        x = net._first_input(clip[:, 1], state, z)
        kept = apply_head(clip[:, 1], z, "curve")
        assert x.shape[1] == 7 and torch.allclose(x[:, 6], RANK_SCALE * rank_change(kept, state[3])[:, None, None])
        assert torch.equal(net._first_input(frame, None, torch.zeros_like(z))[:, 6], torch.zeros(1, 32, 32))
        assert not torch.allclose(net(clip), delta(clip))
    save_weights(net, tmp_path / "rank.safetensors", {"name": "rank", "head": "curve", "inputs": "delta-rank"})
    assert load_weights(tmp_path / "rank.safetensors").net.inputs == "delta-rank"


def test_the_enhancement_record_names_the_input_only_when_it_is_not_the_papers(tmp_path: Path) -> None:
    for inputs in ("rgb", "rgb-log", "rgb-prev", "delta", "delta-rank"):
        weights = random_head_weights("gain-gamma", tmp_path / f"{inputs}.safetensors", "2" * 64, inputs=inputs)
        params = RecurrentGammaMethod(weights=weights, device="cpu").parameters()
        assert params.get("inputs") == (None if inputs == "rgb" else inputs)


@pytest.mark.parametrize(
    ("inputs", "says"),
    [
        ("rgb", None),
        ("rgb-log", "log intensity"),
        ("rgb-prev", "z_last"),
        ("delta", "z = z_last + out"),
        ("delta-rank", "Goodman-Kruskal gamma"),
    ],
)
def test_the_card_says_what_the_network_reads(inputs: str, says: str | None) -> None:
    cfg = TrainConfig(head="gain-gamma", inputs=inputs, objective="relative")
    card = model_card(GammaNet(head="gain-gamma", inputs=inputs), cfg, "n", [], {}, None)
    assert card["inputs"] == inputs and card["training"]["inputs"] == inputs
    assert ("input:" not in card["architecture"]) if says is None else (says in card["architecture"])


def test_unknown_inputs_are_refused_in_one_line() -> None:
    with pytest.raises(OptionError, match="unknown inputs 'gray'"):
        GammaNet(inputs="gray")
    with pytest.raises(OptionError, match="inputs must be one of rgb, rgb-log, rgb-prev, delta, delta-rank"):
        TrainConfig(inputs="gray")


def test_the_papers_head_started_from_a_network_that_carries_a_correction_reads_rgb() -> None:
    for inputs in ("rgb", "rgb-log", "rgb-prev", "delta", "delta-rank"):
        net = GammaNet(head="gain-gamma", inputs=inputs)
        assert net.inputs_for_head("gain-gamma") == inputs
        assert net.inputs_for_head("gamma") == ("rgb" if inputs in ("rgb-prev", "delta", "delta-rank") else inputs)
        GammaNet(head="gamma", inputs=net.inputs_for_head("gamma"))  # a network that can be built
