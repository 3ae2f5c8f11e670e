"""``examples/cpp_host``: the C++ host, compiled with g++ against ONNX Runtime, runs an exported step over a real
clip with the state carried, and its per-frame outputs, corrections and enhanced frames match colonlight's own
(torch) for every head the sidecar describes."""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("onnxruntime", reason="the export extra (onnxruntime) is not installed")
pytest.importorskip("onnxscript", reason="the export extra (onnxscript) is not installed")

from colonlight.checkpoint import LoadedWeights, load_weights  # noqa: E402
from colonlight.curves import IDENTITY_LUT
from colonlight.methods.rnn import PRESAMPLE, RecurrentGammaMethod, head_correction  # noqa: E402
from colonlight.onnx_export import export_onnx, onnx_sidecar_path  # noqa: E402
from colonlight.tone_match import ToneMatcher

from ...media import synthetic_clip_frames  # noqa: E402
from ...networks import random_head_weights  # noqa: E402

WIDTH, HEIGHT, FRAMES = 256, 208, 30
#: The random heads' network size: 208 > 8 x 24, so their frames take the host's bilinear presample before the
#: area average, while the shipped and authors' (48 px) are area-averaged at once: both branches of the resize
RANDOM_HEAD_SIZE = 24
TOLERANCE = 1e-5


@pytest.fixture(scope="module")
def host(cpp_host: Path) -> Path:
    """``colonlight_host``, built once for the session (tests/conftest.py)."""
    return cpp_host


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> list[np.ndarray]:
    """A synthetic colonoscopy clip with its lighting changes, written as H.264 and decoded (RGB)."""
    frames = synthetic_clip_frames(tmp_path_factory.mktemp("clip") / "clip.mp4", FRAMES, WIDTH, HEIGHT, seed=5)
    assert len(frames) == FRAMES and frames[0].shape == (HEIGHT, WIDTH, 3)
    return frames


def _weights(which: str, tmp_path: Path, request: pytest.FixtureRequest) -> tuple[LoadedWeights, int]:
    if which == "shipped":
        weights = load_weights()
        return weights, int(weights.card["input_size"])
    if which == "authors":
        return load_weights(request.getfixturevalue("authors_checkpoint")), 48
    return random_head_weights(which, tmp_path / f"{which}.safetensors", "3" * 64), RANDOM_HEAD_SIZE


def _run_host(host: Path, onnx: Path, frames: list[np.ndarray], out: Path) -> list[dict[str, object]]:
    raw = b"".join(np.ascontiguousarray(f).tobytes() for f in frames)
    result = subprocess.run(
        [str(host), str(onnx), str(WIDTH), str(HEIGHT), "--out", str(out)], input=raw, capture_output=True, timeout=300
    )
    assert result.returncode == 0, result.stderr.decode()
    return [json.loads(line) for line in result.stdout.decode().splitlines()]


def _python_correction(head: str, raw: list[float]) -> tuple[np.ndarray, dict[str, object]]:
    """colonlight's own rule (``methods/rnn.head_correction``) applied to the host's raw outputs: the table
    (identity where the outputs were unusable) and the recorded values."""
    correction = head_correction(head, raw)
    return correction.table, {"gamma": correction.gamma, **correction.extra}


@pytest.mark.parametrize("which", ["shipped", "authors", "gamma", "gain-gamma", "curve"])
def test_the_cpp_host_matches_torch_frame_by_frame(
    which: str, host: Path, clip: list[np.ndarray], tmp_path: Path, request: pytest.FixtureRequest
) -> None:
    weights, size = _weights(which, tmp_path, request)
    assert (min(WIDTH, HEIGHT) > PRESAMPLE * size) == (size == RANDOM_HEAD_SIZE)  # which resize branch it takes
    head = weights.head
    onnx = tmp_path / "model.onnx"
    export_onnx(weights, onnx, size=size)
    records = _run_host(host, onnx, clip, tmp_path / "enhanced.rgb")
    enhanced = np.fromfile(tmp_path / "enhanced.rgb", np.uint8).reshape(-1, HEIGHT, WIDTH, 3)
    assert len(records) == len(enhanced) == FRAMES and [r["index"] for r in records] == list(range(FRAMES))

    method = RecurrentGammaMethod(weights=weights, model_size=size, device="cpu")
    seeds, stream = method.seeds, method.stream()
    # the host's own tone match, run by colonlight's on the host's tables (off for the paper's gamma head)
    matcher = ToneMatcher(method.tone_match) if method.tone_match > 0 else None
    theirs = np.array([r["head"] for r in records], dtype=np.float64)
    ours_raw, moved = [], []
    for i, (frame, record, out) in enumerate(zip(clip, records, enhanced, strict=True)):
        (result,) = stream.push(frame)
        raw = result.info["z"] if head != "gamma" else [result.info["a"]]
        ours_raw.append(raw)
        assert record["seed"] == (i < seeds)
        if record["seed"]:
            assert np.array_equal(out, frame) and record["gamma"] == 1.0
            if matcher is not None:
                matcher.keep(frame, IDENTITY_LUT)
            continue
        # The host's correction is colonlight's rule exactly, given the same raw outputs ...
        lut, values = _python_correction(head, [float(v) for v in record["head"]])
        if matcher is not None:
            lut = matcher.table(frame, lut)
        assert np.array_equal(out, lut[frame]), f"frame {i}: the host's table differs from colonlight's"
        for key, want in values.items():
            assert np.allclose(record[key], want, rtol=0, atol=1e-12), (i, key, record[key], want)
        # ... and within ONNX Runtime's float noise of what colonlight enhance computes with torch.
        assert math.isclose(record["gamma"], result.gamma, rel_tol=0, abs_tol=1e-4)
        if head == "gain-gamma":
            assert math.isclose(record["gain"], result.info["gain"], rel_tol=0, abs_tol=1e-4)
        if head == "curve":
            assert np.max(np.abs(np.array(record["curve"]) - np.array(result.info["curve"]))) <= 1e-4
        assert np.max(np.abs(out.astype(int) - result.frame.astype(int))) <= 1  # a rounding at a .5 at most
        moved.append(result.gamma)
    assert np.max(np.abs(theirs - np.array(ours_raw))) <= TOLERANCE
    assert np.ptp(theirs, axis=0).max() > 1e-3, "the clip must move the network's outputs, or this proves little"
    assert len(moved) == FRAMES - seeds


def test_the_cpp_host_fails_in_one_line(host: Path, tmp_path: Path) -> None:
    usage = subprocess.run([str(host)], capture_output=True, text=True)
    assert usage.returncode == 2 and "usage: colonlight_host" in usage.stderr
    missing = subprocess.run([str(host), str(tmp_path / "none.onnx"), "8", "8"], capture_output=True, text=True)
    assert missing.returncode == 1 and missing.stderr.count("\n") == 1 and "none.onnx.json" in missing.stderr
    # a sidecar from before the presample resize (session 15) is refused, not read with another resize
    onnx = tmp_path / "old.onnx"
    export_onnx(load_weights(), onnx, size=8)
    sidecar = onnx_sidecar_path(onnx)
    side = json.loads(sidecar.read_text())
    del side["inputs"][0]["presample"]
    sidecar.write_text(json.dumps(side))
    old = subprocess.run([str(host), str(onnx), "8", "8"], capture_output=True, text=True, input="")
    assert old.returncode == 1 and old.stderr.count("\n") == 1
    assert "old.onnx.json" in old.stderr and "presample" in old.stderr and "re-export" in old.stderr


def test_the_cpp_host_starts_afresh_at_a_scene_cut(host: Path, clip: list[np.ndarray], tmp_path: Path) -> None:
    """A clip cut to another scene: the host finds the cut where colonlight does, and from there on writes what
    it writes for the second scene alone (its state, frame count and tone match restarted)."""
    from colonlight.synth import SynthConfig, generate_clip

    cfg = SynthConfig.sample(
        np.random.default_rng(13), split="heldout", width=WIDTH, height=HEIGHT, n_frames=12, steady=True
    )
    second = [f.image for f in generate_clip(cfg, seed=13)]
    weights = load_weights()
    method = RecurrentGammaMethod(weights=weights, device="cpu")
    stream = method.stream()
    ours = [r for f in clip + second for r in stream.push(f)]
    cuts = [i for i, r in enumerate(ours) if r.info.get("scene_cut")]
    assert cuts == [FRAMES], f"colonlight must find the cut at frame {FRAMES} for this test to mean anything"
    onnx = tmp_path / "model.onnx"
    export_onnx(weights, onnx, size=method.model_size)
    joined = _run_host(host, onnx, clip + second, tmp_path / "joined.rgb")
    alone = _run_host(host, onnx, second, tmp_path / "alone.rgb")
    assert [i for i, r in enumerate(joined) if r["scene_cut"]] == cuts and not any(r["scene_cut"] for r in alone)
    assert [r["head"] for r in joined[FRAMES:]] == [r["head"] for r in alone]
    frames = np.fromfile(tmp_path / "joined.rgb", np.uint8).reshape(-1, HEIGHT, WIDTH, 3)
    assert np.array_equal(frames[FRAMES:], np.fromfile(tmp_path / "alone.rgb", np.uint8).reshape(frames[FRAMES:].shape))
    for out, result in zip(frames[FRAMES:], ours[FRAMES:], strict=True):  # and colonlight's, to a .5 rounding
        assert np.max(np.abs(out.astype(int) - result.frame.astype(int))) <= 1


def test_the_cpp_host_holds_a_featureless_frame(host: Path, clip: list[np.ndarray], tmp_path: Path) -> None:
    """A black dropout inside the clip: the host holds it where colonlight does (the last table, no state
    change), and every frame after it is what the host writes for the clip without it."""
    at = FRAMES // 2
    flashed_clip = clip[:at] + [np.zeros_like(clip[0])] + clip[at:]
    weights = load_weights()
    method = RecurrentGammaMethod(weights=weights, device="cpu")
    stream = method.stream()
    ours = [r for f in flashed_clip for r in stream.push(f)]
    assert [i for i, r in enumerate(ours) if r.info.get("held")] == [at]
    onnx = tmp_path / "model.onnx"
    export_onnx(weights, onnx, size=method.model_size)
    flashed = _run_host(host, onnx, flashed_clip, tmp_path / "flashed.rgb")
    plain = _run_host(host, onnx, clip, tmp_path / "plain.rgb")
    assert [i for i, r in enumerate(flashed) if r["held"]] == [at] and not any(r["scene_cut"] for r in flashed)
    assert flashed[at]["gamma"] == plain[at - 1]["gamma"] and flashed[at]["head"] == []
    assert [r["head"] for r in flashed[at + 1 :]] == [r["head"] for r in plain[at:]]
    frames = np.fromfile(tmp_path / "flashed.rgb", np.uint8).reshape(-1, HEIGHT, WIDTH, 3)
    alone = np.fromfile(tmp_path / "plain.rgb", np.uint8).reshape(-1, HEIGHT, WIDTH, 3)
    assert np.array_equal(frames[at + 1 :], alone[at:])
    written = alone[at - 1][clip[at - 1] == 0]  # the last table at 0, read off the frame before
    assert written.size and np.all(frames[at] == written[0])
    assert np.max(np.abs(frames[at].astype(int) - ours[at].frame.astype(int))) <= 1  # and colonlight's


def test_the_cpp_host_given_a_content_mask_writes_what_enhance_writes(
    host: Path, clip: list[np.ndarray], tmp_path: Path
) -> None:
    """A clip behind a round border with on-screen text: given the mask `colonlight content` writes, the host shows
    the step the content area as `colonlight enhance --content auto` does, so its corrections are colonlight's and
    every border and text pixel is written as it came in; without the mask the border moves its corrections."""
    from colonlight.content import content_stream, find_content_area
    from colonlight.content_mask import write_content_mask
    from colonlight.synth.overlay import OverlaySpec

    spec = OverlaySpec(border="round", fov=0.9, text=True)
    framed = [spec.apply(f) for f in clip]
    found = find_content_area(framed)
    assert not found.area.is_full and found.area.overlay.any() and not found.changes
    mask = tmp_path / "content.pgm"
    write_content_mask(mask, found.area)
    method = RecurrentGammaMethod(weights=load_weights(), device="cpu")
    stream = content_stream(method, "auto")
    ours = [r for f in framed for r in stream.push(f)] + stream.flush()
    onnx = tmp_path / "model.onnx"
    export_onnx(load_weights(), onnx, size=method.model_size)
    raw = b"".join(np.ascontiguousarray(f).tobytes() for f in framed)
    run = [str(host), str(onnx), str(WIDTH), str(HEIGHT), "--out", str(tmp_path / "masked.rgb"), "--content", str(mask)]
    result = subprocess.run(run, input=raw, capture_output=True, timeout=300)
    assert result.returncode == 0, result.stderr.decode()
    records = [json.loads(line) for line in result.stdout.decode().splitlines()]
    frames = np.fromfile(tmp_path / "masked.rgb", np.uint8).reshape(-1, HEIGHT, WIDTH, 3)
    assert len(records) == len(frames) == len(ours) == FRAMES
    scene = found.area.mask
    for frame, out, record, result_ in zip(framed, frames, records, ours, strict=True):
        assert np.array_equal(out[~scene], frame[~scene])  # border and text exactly as they came in
        assert np.max(np.abs(out.astype(int) - result_.frame.astype(int))) <= 1  # colonlight's, to a .5 rounding
        assert math.isclose(record["gamma"], result_.gamma, rel_tol=0, abs_tol=1e-4)
    whole = _run_host(host, onnx, framed, tmp_path / "whole.rgb")  # the same frames, the border shown to the step
    assert max(abs(a["gamma"] - b["gamma"]) for a, b in zip(whole, records, strict=True)) > 0.05


@pytest.mark.parametrize(
    ("content", "says"),
    [
        (b"P5\n8 8\n255\n" + bytes([255]) * 64, "the mask is 8x8, the frames are 16x12"),
        (b"P2\n16 12\n255\n" + bytes([255]) * 192, "not an 8-bit binary PGM"),
        (b"P5\n16 12\n255\n" + bytes([255]) * 100, "cut short"),
        (b"P5\n16 12\n255\n" + bytes(192), "no scene pixel"),
    ],
)
def test_the_cpp_host_refuses_a_bad_content_mask_in_one_line(
    host: Path, tmp_path: Path, content: bytes, says: str
) -> None:
    onnx = tmp_path / "model.onnx"
    export_onnx(load_weights(), onnx, size=8)
    mask = tmp_path / "mask.pgm"
    mask.write_bytes(content)
    bad = subprocess.run([str(host), str(onnx), "16", "12", "--content", str(mask)], capture_output=True, input=b"")
    message = bad.stderr.decode()
    assert bad.returncode == 1 and message.count("\n") == 1 and str(mask) in message and says in message, message
