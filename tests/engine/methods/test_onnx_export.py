"""``colonlight export``: the step graph run by ONNX Runtime matches torch over a real clip, its sidecar is complete,
and a network whose head has several outputs exports with no change to the exporter."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import pytest
import torch
from torch import Tensor
from typer.testing import CliRunner

pytest.importorskip("onnxruntime", reason="the export extra (onnxruntime) is not installed")
pytest.importorskip("onnxscript", reason="the export extra (onnxscript) is not installed")

from colonlight_cli.main import app  # noqa: E402

from colonlight.checkpoint import LoadedWeights, load_weights  # noqa: E402
from colonlight.correction import CURVE_KNOTS, CURVE_SEGMENTS  # noqa: E402
from colonlight.methods.rnn import (  # noqa: E402
    GAIN_MAX,
    GAIN_MIN,
    GAMMA_MAX,
    GAMMA_MIN,
    PRESAMPLE,
    SEED_FRAMES,
    RecurrentGammaMethod,
    network_input,
)
from colonlight.model import HEAD_OUTPUTS, GammaNet, State  # noqa: E402
from colonlight.onnx_export import export_onnx, onnx_sidecar_path, read_sidecar  # noqa: E402
from colonlight.onnx_step import cpu_session  # noqa: E402
from colonlight.tone_match import DEFAULT_TONE_MATCH, SAMPLE_PIXELS

from ...media import synthetic_clip_frames  # noqa: E402
from ...networks import random_head_weights  # noqa: E402

runner = CliRunner()
CLIP_FRAMES = 100
TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> list[np.ndarray]:
    """A 100-frame synthetic colonoscopy clip (with its lighting disturbances), written as H.264 and decoded."""
    frames = synthetic_clip_frames(tmp_path_factory.mktemp("clip") / "clip.mp4", CLIP_FRAMES, 96, 96, seed=3)
    assert len(frames) == CLIP_FRAMES
    return frames


def _onnx_a(onnx_path: Path, frames: list[np.ndarray]) -> np.ndarray:
    """``a`` per frame as a host would compute it, from the sidecar alone."""
    side = read_sidecar(onnx_path)
    size = side["input_size"]
    session = cpu_session(onnx_path)
    state = {i["name"]: np.zeros(i["shape"], np.float32) for i in side["inputs"] if i["name"] != "frame"}
    names = [o["name"] for o in side["outputs"]]
    out = []
    for frame in frames:
        x = network_input(frame, size).astype(np.float32).transpose(2, 0, 1)[None] / 255.0
        result = dict(zip(names, session.run(None, {"frame": x, **state}), strict=True))
        state = {n: result[f"{n}_out"] for n in state}
        out.append(np.asarray(result[names[0]], np.float64).reshape(-1))  # the head's output(s): a, or z
    return np.array(out)


def _torch_a(weights: Path | None, frames: list[np.ndarray], size: int) -> np.ndarray:
    """The head's output(s) per frame from the rnn method's own stream (the path ``colonlight enhance`` takes)."""
    stream = RecurrentGammaMethod(weights=weights, model_size=size, device="cpu").stream()
    return np.array([stream.predict(f) for f in frames])


def _export(out: Path, *args: str) -> Path:
    result = runner.invoke(app, ["export", "-o", str(out), *args])
    assert result.exit_code == 0, result.output
    return out


@pytest.fixture(scope="module")
def shipped_onnx(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The shipped model exported by the CLI at its default size, into a file named like its weights."""
    return _export(tmp_path_factory.mktemp("onnx") / "colonlight-rnn.onnx")


@pytest.mark.parametrize("which", ["shipped", "authors"])
def test_onnx_runtime_matches_torch_over_a_100_frame_clip(
    which: str, clip: list[np.ndarray], tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    if which == "shipped":
        weights, out = None, request.getfixturevalue("shipped_onnx")
    else:
        weights = request.getfixturevalue("authors_checkpoint")
        out = _export(tmp_path / "authors.onnx", "--weights", str(weights))
    side = read_sidecar(out)
    size = 32 if which == "shipped" else 48  # the shipped card says 32; the authors' .pth has no card: the default
    assert side["input_size"] == size
    onnx_a, torch_a = _onnx_a(out, clip), _torch_a(weights, clip, size)
    assert onnx_a.shape == torch_a.shape and onnx_a.shape[0] == CLIP_FRAMES
    assert torch_a.std() > 1e-3, "the clip must move the network's output, or the comparison proves little"
    assert np.max(np.abs(onnx_a - torch_a)) <= TOLERANCE


def test_sidecar_says_what_a_host_needs(shipped_onnx: Path) -> None:
    out = shipped_onnx
    side = json.loads(onnx_sidecar_path(out).read_text())
    assert onnx_sidecar_path(out).name == "colonlight-rnn.onnx.json"  # never colonlight-rnn.json, a weights card's name
    shipped = load_weights()
    assert side["model"]["name"] == "colonlight-rnn" and side["model"]["sha256"] == shipped.sha256
    assert side["onnx"]["sha256"] == hashlib.sha256(out.read_bytes()).hexdigest()
    assert side["colonlight_version"] and side["input_size"] == 32
    # the shipped model reads a change (input delta): its last correction and last output frame are state too
    state = ["h", "c", "z_last", "y_last"]
    assert [i["name"] for i in side["inputs"]] == ["frame", *state]
    assert side["inputs"][0]["shape"] == [1, 3, 32, 32] and side["inputs"][1]["shape"] == [1, 32, 32, 32]
    width = HEAD_OUTPUTS[shipped.head]  # z_last holds the head's last raw output
    assert side["inputs"][3]["shape"] == [1, width] and side["inputs"][4]["shape"] == [1, 3, 32, 32]
    assert all("zeros" in i["initial"] for i in side["inputs"][1:])
    head_output = "a" if shipped.head == "gamma" else "z"
    assert [o["name"] for o in side["outputs"]] == [head_output, *(f"{n}_out" for n in state)]
    assert "/ 255" in side["inputs"][0]["normalisation"] and "zeros" in side["inputs"][1]["initial"]
    want_seeds = shipped.seed_frames if shipped.seed_frames is not None else SEED_FRAMES
    assert side["seed_frames"]["count"] == want_seeds
    assert side["correction"]["gamma_range"] == [GAMMA_MIN, GAMMA_MAX]
    if shipped.head != "curve":  # the curve head's gamma is a summary: its range is in summary_gamma's text
        assert side["gamma"]["range"] == [GAMMA_MIN, GAMMA_MAX]
    else:
        assert str(GAMMA_MAX) in side["gamma"]["summary_gamma"] and side["gamma"]["knots"] == list(CURVE_KNOTS)
    if shipped.head == "gamma":
        assert side["gamma"]["formula"] == "gamma = 1 / a"
    assert "lut[v]" in side["lut"]["build"] and "LUT" in side["lut"]["apply"]
    assert side["correction"]["head"] == shipped.head
    assert side["check"]["onnxruntime_vs_torch_max_abs_diff"] <= TOLERANCE
    session = cpu_session(out)
    assert [i.name for i in session.get_inputs()] == ["frame", *state]
    assert [tuple(i.shape) for i in session.get_inputs()] == [
        (1, 3, 32, 32),
        (1, 32, 32, 32),
        (1, 32, 32, 32),
        (1, width),
        (1, 3, 32, 32),
    ]
    # the shipped model's tone match, as numbers a host reads (its rule: examples/cpp_host, held to ours there)
    assert side["tone_match"]["weight"] == DEFAULT_TONE_MATCH and side["tone_match"]["sample_pixels"] == SAMPLE_PIXELS


class GainGammaNet(GammaNet):
    """A head with two outputs (a gain and a gamma per frame), as a variant the lead is training might have."""

    def step(self, frame: Tensor, state: State | None = None) -> tuple[tuple[Tensor, Tensor], State]:  # type: ignore[override]
        a, state = super().step(frame, state)
        gain = torch.sigmoid(state[0].mean(dim=(1, 2, 3))) * 2.0
        return (gain, 1.0 / (a + 0.5)), state


def test_a_head_with_two_outputs_exports_unchanged_and_is_named_by_the_card(tmp_path: Path) -> None:
    torch.manual_seed(1)
    net = GainGammaNet().eval()
    card = {
        "name": "gain-gamma-test",
        "input_size": 24,
        "outputs": [
            {"name": "gain", "meaning": "multiply the frame by it"},
            {"name": "gamma", "meaning": "then ** gamma"},
        ],
    }
    weights = LoadedWeights(
        net=net, name="gain-gamma-test", sha256="0" * 64, path=tmp_path / "x.safetensors", card=card
    )
    record = export_onnx(weights, tmp_path / "gg.onnx", size=24)  # any size: the graph is fixed at the one asked
    assert [o["name"] for o in record["outputs"]] == ["gain", "gamma", "h_out", "c_out"]
    assert record["outputs"][0]["meaning"] == "multiply the frame by it"
    assert "note" in record["gamma"]  # no output 'a': the sidecar does not claim colonlight's gamma rule
    assert record["correction"] is None
    session = cpu_session(tmp_path / "gg.onnx")
    rng = np.random.default_rng(0)
    h = c = np.zeros((1, 32, 24, 24), np.float32)
    state: State | None = None
    for _ in range(5):
        x = rng.random((1, 3, 24, 24), dtype=np.float32)
        gain, gamma, h, c = session.run(None, {"frame": x, "h": h, "c": c})
        with torch.inference_mode():
            (t_gain, t_gamma), state = net.step(torch.from_numpy(x), state)
        assert abs(float(gain[0]) - float(t_gain[0])) <= TOLERANCE
        assert abs(float(gamma[0]) - float(t_gamma[0])) <= TOLERANCE


def test_usage_and_input_errors_are_one_line(tmp_path: Path) -> None:
    full = runner.invoke(app, ["export", "-o", str(tmp_path / "x.onnx"), "--model-size", "full"])
    assert full.exit_code == 2 and "fixed input size" in full.output
    bad = tmp_path / "bad.pth"
    bad.write_bytes(b"not a checkpoint")
    result = runner.invoke(app, ["export", "-o", str(tmp_path / "y.onnx"), "--weights", str(bad)])
    assert result.exit_code == 1 and str(bad) in result.output and "Traceback" not in result.output
    assert not (tmp_path / "y.onnx").exists() and not onnx_sidecar_path(tmp_path / "y.onnx").exists()


@pytest.mark.parametrize(
    ("head", "n_outputs", "build", "apply", "inputs"),
    [
        ("gain-gamma", 2, "min(1, gain * (v / 255) ^ gamma)", "out = min(1, gain * in ^ gamma)", "rgb"),
        ("gain-gamma", 2, "min(1, gain * (v / 255) ^ gamma)", "out = min(1, gain * in ^ gamma)", "rgb-log"),
        ("curve", CURVE_SEGMENTS, "min(1, f(v / 255))", "out = min(1, f(in))", "rgb-prev"),
        ("curve", CURVE_SEGMENTS, "min(1, f(v / 255))", "out = min(1, f(in))", "rgb"),
        ("gain-gamma", 2, "min(1, gain * (v / 255) ^ gamma)", "out = min(1, gain * in ^ gamma)", "delta"),
        ("curve", CURVE_SEGMENTS, "min(1, f(v / 255))", "out = min(1, f(in))", "delta-rank"),
    ],
)
def test_a_head_with_raw_outputs_exports_as_z_with_its_correction_and_runs_on_onnxruntime(
    head: str,
    n_outputs: int,
    build: str,
    apply: str,
    inputs: str,
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """The gain-gamma and curve heads (random output layers, so the outputs move): one output ``z``, the sidecar's
    rule, table and correction numbers for that head, and the rnn method on ONNX Runtime matching torch; a
    network that reads the log intensity too computes it inside the graph (the host still sends RGB), and one that
    reads the frame under the last correction carries that correction's outputs as a third state tensor (and a
    ``delta`` network the last output frame as a fourth, all zeros at the start like the others)."""
    monkeypatch.setenv("COLONLIGHT_CACHE_DIR", str(tmp_path / "cache"))
    weights = random_head_weights(head, tmp_path / "w.safetensors", "1" * 64, inputs=inputs)
    if inputs != "rgb":
        with torch.no_grad():  # the extra channels must matter for the comparison to test them
            weights.net.in_cnv.weight[:, 3:].normal_(0.0, 0.2)
    record = export_onnx(weights, tmp_path / "w.onnx", size=32)
    refines = ["h", "c", "z_last", "y_last"]
    state = {"rgb-prev": ["h", "c", "z_last"], "delta": refines, "delta-rank": refines}.get(inputs, ["h", "c"])
    assert [o["name"] for o in record["outputs"]] == ["z", *(f"{n}_out" for n in state)]
    assert [i["name"] for i in record["inputs"]] == ["frame", *state]
    assert record["outputs"][0]["shape"] == [1, n_outputs] and record["seed_frames"]["count"] == 0
    assert record["gamma"]["from_output"] == "z"
    assert build in record["lut"]["build"] and apply in record["lut"]["apply"] and "^ gamma on" not in apply
    assert record["correction"]["head"] == head and record["correction"]["gamma_range"] == [GAMMA_MIN, GAMMA_MAX]
    assert record["network_inputs"] == inputs
    assert record["inputs"][0]["presample"] == PRESAMPLE and f"{PRESAMPLE * 32}" in record["inputs"][0]["resize"]
    if head == "curve":
        assert record["gamma"]["knots"] == record["correction"]["knots"] == list(CURVE_KNOTS)
    else:
        assert "gain" in record["gamma"]["formula"] and record["correction"]["gain_range"] == [GAIN_MIN, GAIN_MAX]
    rng = np.random.default_rng(4)
    frames = [(rng.random((40, 40, 3)) * 255).astype(np.uint8) for _ in range(6)]
    torch_stream = RecurrentGammaMethod(weights=weights, device="cpu").stream()
    onnx_stream = RecurrentGammaMethod(weights=weights, device="cpu", runtime="onnxruntime").stream()
    for f in frames:
        ours, theirs = torch_stream.push(f)[0], onnx_stream.push(f)[0]
        assert np.max(np.abs(np.array(ours.info["z"]) - np.array(theirs.info["z"]))) <= TOLERANCE
        assert abs(ours.gamma - theirs.gamma) <= 1e-4
        assert np.max(np.abs(ours.frame.astype(int) - theirs.frame.astype(int))) <= 1
        if head == "gain-gamma":
            assert abs(ours.info["gain"] - theirs.info["gain"]) <= 1e-4
