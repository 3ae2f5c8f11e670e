"""The other commands: synth, train, demo, device errors."""

from __future__ import annotations

import json
from pathlib import Path

import av
import cv2
import numpy as np
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

runner = CliRunner()
#: ``colonlight train`` flags for the smallest synthetic run: 12-frame clips at 48 px, one validation clip
TINY_SYNTHETIC = ("--synthetic-frames", "12", "--synthetic-val", "1", "--synthetic-size", "48")


def test_synth_command_writes_clips_with_ground_truth(tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        [
            "synth",
            str(tmp_path / "s"),
            "--clips",
            "2",
            "--frames",
            "12",
            "--width",
            "96",
            "--height",
            "80",
            "--seed",
            "5",
            "--workers",
            "1",
        ],
    )
    assert result.exit_code == 0, result.output
    clips = sorted(p for p in (tmp_path / "s").iterdir() if p.is_dir())
    assert len(clips) == 2
    for c in clips:
        assert len(list((c / "frames").glob("*.png"))) == 12
        assert len((c / "poses.txt").read_text().strip().splitlines()) == 12
        with av.open(str(c / "clip.mp4")) as v:
            assert sum(1 for _ in v.decode(video=0)) == 12
        assert json.loads((c / "synth.json").read_text())["seed"] in (5, 6)


def test_synth_mix_renders_the_clips_train_renders_for_itself(tmp_path: Path) -> None:
    """``synth --steady/--occluders/--clean-seeds`` draws the mix as ``train --synthetic-*`` does, so a run's
    extra clips can be rendered ahead by the same command line, frame for frame."""
    from colonlight.synth import make_dataset

    size = ("--frames", "6", "--width", "48", "--height", "40", "--workers", "1", "--no-video", "--seed", "3")
    result = runner.invoke(
        app, ["synth", str(tmp_path / "s"), "-n", "2", *size, "--steady", "1", "--occluders", "1", "--clean-seeds", "1"]
    )
    assert result.exit_code == 0, result.output
    expected = make_dataset(
        tmp_path / "m", 2, seed=3, width=48, height=40, n_frames=6, workers=1, steady_fraction=1.0,
        occluder_fraction=1.0, clean_seeds_fraction=1.0,
    )  # fmt: skip
    for made in expected:
        config = json.loads((made / "synth.json").read_text())["config"]
        assert config["steady"] and config["undisturbed_seeds"] and config["close_occluder"] == "force"
        rendered = tmp_path / "s" / made.name
        for png in sorted((made / "frames").glob("*.png")):
            assert (rendered / "frames" / png.name).read_bytes() == png.read_bytes()
    plain = runner.invoke(app, ["synth", str(tmp_path / "p"), "-n", "1", *size])
    assert plain.exit_code == 0, plain.output
    assert not json.loads((tmp_path / "p" / "clip_00000" / "synth.json").read_text())["config"]["steady"]


def test_synth_rejects_bad_split(tmp_path: Path) -> None:
    assert runner.invoke(app, ["synth", str(tmp_path), "--split", "test"]).exit_code == 2


def test_train_command_on_synthetic_clips(tmp_path: Path) -> None:
    result = runner.invoke(
        app,
        [
            "train",
            "--synthetic",
            "2",
            *TINY_SYNTHETIC,
            "--size",
            "32",
            "--epochs",
            "1",
            "-o",
            str(tmp_path / "run"),
            "--synthetic-occluders",
            "0.5",
            "--anchor",
            "0.05",
        ],
    )
    assert result.exit_code == 0, result.output
    card = json.loads((tmp_path / "run" / "colonlight-rnn.json").read_text())
    assert (
        card["training"]["command"].startswith("colonlight train ") and "--synthetic 2 " in card["training"]["command"]
    )
    assert (
        "seeds 1000..1001" in card["training"]["data"]
        and "50% forced to have a close-occluder" in card["training"]["data"]
    )
    assert card["training"]["anchor"] == 0.05 and "brightness anchor" in card["training"]["objective"]
    assert len(card["training"]["history"]) == 1
    exported = runner.invoke(app, ["train", "-o", str(tmp_path / "run"), "--export-epoch", "1"])
    assert exported.exit_code == 0, exported.output
    assert (tmp_path / "run" / "colonlight-rnn-epoch001.safetensors").is_file()
    epoch_card = json.loads((tmp_path / "run" / "colonlight-rnn-epoch001.json").read_text())
    assert epoch_card["sha256"] == card["sha256"] and epoch_card["training"]["shipped_epoch"] == 1
    missing = runner.invoke(app, ["train", "-o", str(tmp_path / "run"), "--export-epoch", "2"])
    assert missing.exit_code == 1 and "no saved state for epoch 2" in missing.output
    assert "Traceback" not in missing.output and len(missing.output.strip().splitlines()) == 1
    state = tmp_path / "run" / "checkpoints" / "epoch_001.json"
    kept = state.read_bytes()
    state.write_bytes(b"[" * 100_000)  # nested past the JSON decoder's depth: a RecursionError, not a ValueError
    deep = runner.invoke(app, ["train", "-o", str(tmp_path / "run"), "--export-epoch", "1"])
    assert deep.exit_code == 1 and "unreadable training state" in deep.output, deep.output
    assert "Traceback" not in deep.output and len(deep.output.strip().splitlines()) == 1
    state.write_bytes(kept)
    out = runner.invoke(
        app,
        [
            "enhance",
            str(tmp_path / "run" / "data" / "val"),
            "-o",
            str(tmp_path / "o"),
            "--weights",
            str(tmp_path / "run" / "colonlight-rnn.safetensors"),
            "-q",
        ],
    )
    assert out.exit_code == 0, out.output


def test_train_needs_data(tmp_path: Path) -> None:
    assert runner.invoke(app, ["train", "-o", str(tmp_path)]).exit_code == 2


def test_demo_runs_end_to_end_on_the_shipped_model(tmp_path: Path) -> None:
    """`colonlight demo`: renders a clip, enhances it with the default model, prints where everything is."""
    result = runner.invoke(app, ["demo", "-o", str(tmp_path / "demo"), "--frames", "30", "-q"])
    assert result.exit_code == 0, result.output
    out = tmp_path / "demo" / "enhanced" / "clip"
    g = json.loads((out / "gammas.json").read_text())
    assert g["model"]["name"] == "colonlight-rnn" and g["frame_count"] == 18  # 1 s at 30 fps -> 18 frames
    assert len(list((out / "frames").glob("*.png"))) == 18 and (out / "enhanced.mp4").is_file()
    for word in ("enhanced frames", "per-frame gamma", "enhanced video", str(out / "gammas.json")):
        assert word in result.output.replace("\n", "")


def test_info_shows_the_default_model_card() -> None:
    result = runner.invoke(app, ["info", "--json"])
    info = json.loads(result.output)
    card = info["default_model"]["card"]
    from colonlight.methods.rnn import DEFAULT_MODEL_SIZE

    # the shipped model was trained at the default size and runs at 32 px since session 22, which its card says
    assert card["name"] == "colonlight-rnn" and card["training"]["size"] == DEFAULT_MODEL_SIZE
    assert card["input_size"] == 32 and "32" in card["input_size_note"]
    assert "synthetic" in card["training"]["data"] and card["training"]["history"]


def test_train_defaults_to_the_inference_size() -> None:
    import inspect

    from colonlight_cli.train import train_cmd

    from colonlight.methods.rnn import DEFAULT_MODEL_SIZE
    from colonlight.train import TrainConfig

    assert inspect.signature(train_cmd).parameters["size"].default.default == TrainConfig().size == DEFAULT_MODEL_SIZE


def _fine_tune(tmp_path: Path, name: str, *extra: str) -> dict:  # type: ignore[type-arg]
    result = runner.invoke(
        app,
        [
            "train",
            "--synthetic",
            "1",
            *TINY_SYNTHETIC,
            "--epochs",
            "1",
            "--seq-len",
            "4",
            "--stride",
            "4",
            "--init",
            "default",
            "-o",
            str(tmp_path / name),
            *extra,
        ],
    )
    assert result.exit_code == 0, result.output
    return json.loads((tmp_path / name / "colonlight-rnn.json").read_text())  # type: ignore[no-any-return]


def test_fine_tuning_keeps_the_starting_models_head_unless_told(tmp_path: Path) -> None:
    from colonlight import load_weights

    shipped = load_weights(None).net.head
    assert shipped != "gamma"  # else this test could not tell the two defaults apart
    assert _fine_tune(tmp_path, "kept")["head"] == shipped
    assert _fine_tune(tmp_path, "asked", "--head", "gamma")["head"] == "gamma"


@pytest.mark.parametrize(
    ("name", "content", "design"),
    [
        ("broken.safetensors", b"not a checkpoint", []),
        ("broken.pth", b"junk\n", []),  # the weights-only unpickler fails on it with a KeyError
        # with the design given, --init is still read first: before hours of rendering, not after
        ("broken.pth", b"junk\n", ["--head", "curve", "--inputs", "delta", "--synthetic", "500"]),
    ],
)
def test_train_with_an_unreadable_init_is_an_error_naming_it(
    tmp_path: Path, name: str, content: bytes, design: list[str]
) -> None:
    bad = tmp_path / name
    bad.write_bytes(content)
    args = ["train", str(tmp_path), "--init", str(bad), "-o", str(tmp_path / "r"), *design]
    result = runner.invoke(app, args, env={"COLUMNS": "400"})  # rich would wrap a long path inside its box
    unboxed = "".join(ch for ch in result.output if not ch.isspace() and ch not in "│╭╮╰╯─")  # however it wrapped
    assert result.exit_code in (1, 2) and name in unboxed, result.output
    assert result.exception is None or isinstance(result.exception, SystemExit), result.exception
    assert "Traceback" not in result.output


def test_train_leaves_out_an_unreadable_clip_names_it_and_exits_1_with_the_model_written(tmp_path: Path) -> None:
    data = tmp_path / "data"
    data.mkdir()
    rng = np.random.default_rng(0)
    for name in ("a.mp4", "c.mp4"):  # real videos, the flicker a training run is for
        writer = cv2.VideoWriter(str(data / name), cv2.VideoWriter_fourcc(*"mp4v"), 18, (48, 48))
        for _ in range(24):
            writer.write(rng.integers(20, 200, (48, 48, 3), dtype=np.uint8))
        writer.release()
    (data / "b.mp4").write_bytes(b"junk, not a video")
    out = tmp_path / "run"
    args = ["train", str(data), "-o", str(out), "--epochs", "1", "--seq-len", "8", "--size", "32"]
    result = runner.invoke(app, args, env={"COLUMNS": "400"})
    assert result.exit_code == 1, result.output
    assert "skipped" in result.output and "b.mp4: not a video" in result.output
    assert "1 clip(s) could not be used and were left out" in result.output and "Traceback" not in result.output
    card = json.loads((out / "colonlight-rnn.json").read_text())
    assert [line.split(":")[0].endswith("b.mp4") for line in card["training"]["skipped_clips"]] == [True]
