"""Content area (``--content auto``): detection of the field of view and fixed text on generated clips, border and
text pixels written unchanged, gammas on a bordered clip close to those of the same clip without its border, and
``auto`` bit-identical to ``full`` on clips without a border.

The scene is one rendered synthetic clip (module fixture); borders and text are drawn on it with
:mod:`colonlight.synth.overlay`, whose masks are the truth.
"""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from colonlight.content import DETECT_FRAMES, BlockStats, ContentStream, detect_area, iou, live_content_stream
from colonlight.methods import create_method
from colonlight.methods.rnn import RecurrentGammaMethod, head_correction
from colonlight.pipeline import ClipOptions, enhance_clip
from colonlight.synth import SynthConfig, generate_clip
from colonlight.synth.overlay import OverlaySpec

from ...media import make_clip

SIZE = (256, 192)  # width, height: 4:3 like a scope's picture
N_FRAMES = 2 * DETECT_FRAMES
runner = CliRunner()


@pytest.fixture(scope="module")
def scene() -> np.ndarray:
    """``(N, H, W, 3)`` frames of a moving synthetic clip (seed 1: the camera travels, the lighting flickers)."""
    cfg = SynthConfig.sample(
        np.random.default_rng([1, 0]), split="train", width=SIZE[0], height=SIZE[1], n_frames=N_FRAMES
    )
    return np.stack([f.image for f in generate_clip(cfg, seed=1)])


def drawn(frames: np.ndarray, spec: OverlaySpec) -> np.ndarray:
    return np.stack([spec.apply(f) for f in frames])


def truth(spec: OverlaySpec) -> tuple[np.ndarray, np.ndarray]:
    """``(fov, content)`` masks as drawn: content = field of view less text."""
    fov, text = spec.masks(SIZE[1], SIZE[0])
    return fov, fov & ~text


def block_area(frames: np.ndarray) -> object:
    stats = BlockStats()
    for f in frames[:DETECT_FRAMES]:
        stats.add(f)
    return detect_area(stats)


def write_folder(folder: Path, frames: np.ndarray) -> Path:
    folder.mkdir(parents=True)
    for i, f in enumerate(frames):
        cv2.imwrite(str(folder / f"{i:06d}.png"), cv2.cvtColor(f, cv2.COLOR_RGB2BGR))
    return folder


def read_frames(folder: Path) -> list[np.ndarray]:
    return [cv2.cvtColor(cv2.imread(str(p)), cv2.COLOR_BGR2RGB) for p in sorted(folder.glob("*.png"))]


def run_stream(stream: object, frames: np.ndarray) -> list:
    results = []
    for f in frames:
        results += stream.push(f)  # type: ignore[attr-defined]
    return results + stream.flush()  # type: ignore[attr-defined]


# ----------------------------------------------------------------------------------------------- detection


@pytest.mark.parametrize(
    "spec",
    [
        OverlaySpec("round"),
        OverlaySpec("octagon"),
        OverlaySpec("round", text=True),
        OverlaySpec("octagon", text=True),
        OverlaySpec("round", fov=0.8, text=True),
        OverlaySpec("none", text=True),
    ],
    ids=lambda s: f"{s.border}-{s.fov}-{'text' if s.text else 'plain'}",
)
def test_detects_field_of_view_and_text(scene: np.ndarray, spec: OverlaySpec) -> None:
    fov, content = truth(spec)
    area = block_area(drawn(scene, spec))
    assert iou(area.fov, fov) >= 0.98  # measured 0.990 .. 1.000
    assert iou(area.mask, content) >= 0.98
    text_in_fov = fov & ~content
    if text_in_fov.sum() > 100:  # text over the picture (not only on the border): nearly all of it kept out
        assert (text_in_fov & ~area.mask).sum() >= 0.9 * text_in_fov.sum()


def test_no_border_no_text_is_the_full_frame(scene: np.ndarray) -> None:
    """Plain frames, also dark ones (underexposure is what colonlight is for) and a flickering still scene."""
    for scale in (1.0, 0.3, 0.1):
        dark = np.clip(scene.astype(np.float32) * scale, 0, 255).astype(np.uint8)
        assert block_area(dark).is_full, scale
    rng = np.random.default_rng(0)
    still = np.stack(
        [
            np.clip(scene[0] * (1 + 0.3 * np.sin(i)) + rng.normal(0, 1, scene[0].shape), 0, 255)
            for i in range(DETECT_FRAMES)
        ]
    ).astype(np.uint8)
    assert block_area(still).is_full


def test_detection_on_an_h264_clip_from_colonlight_synth(tmp_path: Path) -> None:
    """`colonlight synth --border octagon --text` writes content.png; detection on its decoded mp4 matches it."""
    out = tmp_path / "syn"
    result = runner.invoke(
        app,
        [
            "synth",
            str(out),
            "--frames",
            str(DETECT_FRAMES),
            "--width",
            "192",
            "--height",
            "144",
            "--border",
            "octagon",
            "--text",
            "--seed",
            "3",
            "-j",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    clip = out / "clip_00000"
    meta = json.loads((clip / "synth.json").read_text())
    assert meta["overlay"] == {"border": "octagon", "fov": 0.96, "text": True}
    expected = cv2.imread(str(clip / "content.png"), cv2.IMREAD_GRAYSCALE) > 0
    with av.open(str(clip / "clip.mp4")) as container:
        frames = np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])
    assert iou(block_area(frames).mask, expected) >= 0.95  # measured 0.98 (H.264 softens the edges)
    bad = runner.invoke(app, ["synth", str(tmp_path / "x"), "--border", "hexagon"])
    assert bad.exit_code == 2 and "--border" in bad.output


# ----------------------------------------------------------------------------------------------- outputs


@pytest.mark.parametrize(
    "spec", [OverlaySpec("round", text=True), OverlaySpec("octagon", text=True)], ids=["round", "octagon"]
)
def test_border_and_text_pixels_unchanged(scene: np.ndarray, spec: OverlaySpec, tmp_path: Path) -> None:
    """The shipped model through the pipeline: outside the drawn content every output pixel is the input's."""
    frames = drawn(scene, spec)
    _, content = truth(spec)
    enhance_clip(write_folder(tmp_path / "clip", frames), tmp_path / "out", create_method("rnn"), ClipOptions(fps=None))
    out = read_frames(tmp_path / "out" / "frames")
    assert len(out) == len(frames)
    for f_in, f_out in zip(frames, out, strict=True):
        assert np.array_equal(f_out[~content], f_in[~content])
    record = json.loads((tmp_path / "out" / "gammas.json").read_text())
    assert record["settings"]["content"] == "auto"
    assert record["frames"][0]["content"]["fov_fraction"] < 0.95  # the area is recorded with the first frame
    changed = [not np.array_equal(a[content], b[content]) for a, b in zip(frames, out, strict=True)]
    assert sum(changed) >= len(frames) - 2 - 3  # the content is enhanced (seed frames and gamma ~ 1 aside)


@pytest.mark.parametrize("method", ["he", "deflicker"])
def test_any_method_keeps_border_pixels(scene: np.ndarray, method: str) -> None:
    """A frame-statistics method and a look-ahead method (results held back) behind the same wrapper."""
    spec = OverlaySpec("octagon", text=True)
    frames = drawn(scene, spec)
    _, content = truth(spec)
    results = run_stream(ContentStream(create_method(method).stream()), frames)
    assert len(results) == len(frames)
    for f_in, res in zip(frames, results, strict=True):
        assert np.array_equal(res.frame[~content], f_in[~content])
    plain = run_stream(create_method(method).stream(), frames)
    assert any(not np.array_equal(a.frame[content], b.frame[content]) for a, b in zip(results, plain, strict=True))


def applied_tables(method: RecurrentGammaMethod, results: list) -> np.ndarray:
    """``(N, 256)`` tables the stream applied, rebuilt from each frame's raw outputs by the stream's own rule
    (``head_correction``), the release's two seed frames dropped whatever the weights' seed count."""
    head = method.weights.head
    raws = [r.info["z"] if "z" in r.info else [r.info["a"]] for r in results]
    return np.array([head_correction(head, raw).table for raw in raws], dtype=float)[2:]


def test_corrections_match_the_clip_without_its_border(scene: np.ndarray) -> None:
    """Compared as the tables applied (mean |difference| over the 256 input levels, in 8-bit levels), which any
    head gives; a gain-gamma head can hold its gamma and move its gain, a curve head's summary gamma moves with
    its dark end. Tolerance: the bordered clip hides picture the plain clip shows (an octagon at 0.96 keeps 89%
    of the frame, a disc of 0.96 x height keeps 54%), so the network sees less; the correction may move by that
    much and no more. Measured on seeds 1 and 2, 54 frames, with the curve default and the gain-gamma default
    before it: octagon max 0.9-3.4 levels (full on the bordered clip: 2.4-5.9); disc mean 1.8-6.6 (full: 68-102).
    On seed 3 the hidden corners carry what both models key on: there the octagon moves the table by up to 14
    levels with the area as without it."""
    # at 48 px, the size these numbers were measured at (the shipped card runs 32 px since session 22; there the
    # octagon moves the table as much with the area as without it, 3.6 and 3.5 levels, both within 5)
    method = create_method("rnn", model_size=48)
    assert isinstance(method, RecurrentGammaMethod)
    plain = applied_tables(method, run_stream(method.stream(), scene))
    for spec, stat, tol, apart in (
        (OverlaySpec("octagon", text=True), np.max, 5.0, 1.5),
        (OverlaySpec("round", text=True), np.mean, 10.0, 4.0),
    ):
        frames = drawn(scene, spec)
        auto = applied_tables(method, run_stream(ContentStream(method.stream()), frames))
        full = applied_tables(method, run_stream(method.stream(), frames))
        dev_auto = float(stat(np.abs(auto - plain).mean(axis=1)))
        dev_full = float(stat(np.abs(full - plain).mean(axis=1)))
        assert dev_auto <= tol, (spec, dev_auto, dev_full)
        assert dev_full > apart * dev_auto, (spec, dev_auto, dev_full)  # the border does move the correction


def _without_content_setting(path: Path) -> dict:
    record = json.loads(path.read_text())
    assert record["settings"].pop("content") in ("auto", "full")
    return record


def test_auto_is_bit_identical_on_clips_without_a_border(scene: np.ndarray, tmp_path: Path) -> None:
    """The CLI with the shipped model, --content auto vs full: same frame bytes, same gammas.json (but for the
    recorded content setting), on a synthetic clip and on an H.264 test clip."""
    inputs = [write_folder(tmp_path / "synthetic", scene), make_clip(tmp_path / "index.mp4", n_frames=30, fps=25)]
    outs = {}
    for mode in ("auto", "full"):
        out = tmp_path / mode
        result = runner.invoke(
            app, ["enhance", *map(str, inputs), "-o", str(out), "-q", "--fps", "0", "--content", mode]
        )
        assert result.exit_code == 0, result.output
        outs[mode] = out
    for clip in ("synthetic", "index"):
        a, b = outs["auto"] / clip, outs["full"] / clip
        frames_a = sorted((a / "frames").iterdir())
        assert len(frames_a) >= 30
        assert [p.read_bytes() for p in frames_a] == [p.read_bytes() for p in sorted((b / "frames").iterdir())]
        assert _without_content_setting(a / "gammas.json") == _without_content_setting(b / "gammas.json")
    gammas = [f["gamma"] for f in json.loads((outs["auto"] / "synthetic" / "gammas.json").read_text())["frames"]]
    assert any(abs(g - 1.0) > 0.01 for g in gammas)  # the model did something to compare


# ----------------------------------------------------------------------------------------------- changes


def test_area_changes_only_after_agreeing_blocks(scene: np.ndarray) -> None:
    """A border that appears mid-clip is adopted after two blocks; a dark moment does not drop it."""
    spec = OverlaySpec("octagon")
    fov, _ = truth(spec)
    bordered = drawn(scene, spec)
    dark = (bordered[:DETECT_FRAMES] // 40).astype(np.uint8)  # scope in the dark: everything unlit
    frames = np.concatenate([scene, bordered, dark, bordered])
    stream = ContentStream(create_method("none").stream())
    results = run_stream(stream, frames)
    notes = [(i, r.info["content"]) for i, r in enumerate(results) if "content" in r.info]
    assert len(notes) == 1, notes
    index, note = notes[0]
    # Blocks of the border start at frame 36; the second agreeing one ends at 71; the next frame has the area.
    assert index == len(scene) + 2 * DETECT_FRAMES, notes
    assert iou(stream.area.fov, fov) >= 0.98 and note["fov_fraction"] < 0.95  # type: ignore[union-attr]


def test_bad_content_option_is_refused(tmp_path: Path) -> None:
    result = runner.invoke(app, ["enhance", str(tmp_path), "--content", "border"])
    assert result.exit_code == 2 and "content" in result.output
    with pytest.raises(ValueError, match="content must be auto, full or a mask image: border: cannot read"):
        ClipOptions(content="border")


def test_a_new_frame_size_is_a_clear_error() -> None:
    stream = ContentStream(create_method("none").stream(), detect_frames=2)
    for i in range(3):
        stream.push(np.full((20, 30, 3), 100 + i, np.uint8))
    with pytest.raises(ValueError, match="30x21, the stream started at 30x20"):
        stream.push(np.zeros((21, 30, 3), np.uint8))


# ----------------------------------------------------------------------------------------------- live sources


def test_a_live_stream_finds_a_disc_on_its_first_frame_and_holds_nothing_back(scene: np.ndarray) -> None:
    """Seen whole, a disc border drives the shipped network to its brightest (session 26: gamma 0.12, the field
    of view near white). A live stream cannot hold 18 frames back to look: it finds the disc on the first frame,
    answers every frame as it comes, writes the border unchanged and corrects the picture as it would without
    the border."""
    spec = OverlaySpec("round", text=False)
    fov, _ = truth(spec)
    frames = drawn(scene, spec)
    method = create_method("rnn")
    stream = live_content_stream(method)
    results = []
    for i, f in enumerate(frames):
        got = stream.push(f)
        assert len(got) == 1, i  # nothing held back
        results += got
    assert "content" in results[0].info and results[0].info["content"]["fov_fraction"] < 0.9
    assert all(np.array_equal(r.frame[~fov], f[~fov]) for r, f in zip(results, frames, strict=True))
    whole = run_stream(method.stream(), frames)
    plain = run_stream(method.stream(), scene)

    def level(rs: list) -> float:  # mean grey inside the field of view, after the two seed frames
        return float(np.mean([cv2.cvtColor(r.frame, cv2.COLOR_RGB2GRAY)[fov].mean() for r in rs[2:]]))

    assert abs(level(results) - level(plain)) < 12, (level(results), level(plain), level(whole))
    assert level(whole) - level(plain) > 3 * abs(level(results) - level(plain))  # the border does move it


def test_a_live_stream_finds_the_area_again_at_a_new_frame_size(scene: np.ndarray) -> None:
    """A reconnect may bring another frame size: the live stream finds that picture's area (and the method's
    stream, with its state, goes on), where a clip's stream refuses the frame (above)."""
    octagon = drawn(scene[:4], OverlaySpec("octagon"))
    small = np.stack([cv2.resize(f, (SIZE[0] // 2, SIZE[1] // 2), interpolation=cv2.INTER_AREA) for f in scene[4:8]])
    stream = live_content_stream(create_method("none"))
    results = [r for f in np.concatenate([octagon]) for r in stream.push(f)]
    assert stream.area is not None and not stream.area.is_full  # type: ignore[attr-defined]
    results += [r for f in small for r in stream.push(f)]
    assert [r.frame.shape for r in results] == [f.shape for f in octagon] + [f.shape for f in small]
    assert stream.area is not None and stream.area.is_full  # type: ignore[attr-defined]  # no border when small
    assert results[4].info.get("content") == {"full": True}
