"""`colonlight enhance` end to end, on real video files made by the tests.

Most tests drive the typer app in-process; the resume test kills a real `colonlight` process with SIGKILL.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import threading
import time
from pathlib import Path

import av
import numpy as np
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from ..commands import colonlight_command
from ..media import make_clip, make_image_folder, text_file, truncated_copy, zero_byte_file
from ..outputs import output_bytes, tree_bytes

runner = CliRunner()


def invoke(*args: str) -> tuple[int, str]:
    result = runner.invoke(app, [str(a) for a in args])
    return result.exit_code, result.output


@pytest.fixture()
def tree(tmp_path: Path) -> Path:
    """videos/site1/p7.mp4 (25 fps, 2 s), videos/site 2/clip ü.mov (30 fps), videos/seq/ (12 PNG frames), a text
    file."""
    root = tmp_path / "videos"
    make_clip(root / "site1" / "p7.mp4", n_frames=50, fps=25)
    make_clip(root / "site 2" / "clip ü.mov", n_frames=30, fps=30)
    make_image_folder(root / "seq", n=12)
    text_file(root / "notes.txt")
    return root


def test_tree_layout_and_gammas(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    out = tmp_path / "out"
    code, text = invoke("enhance", tree, "-o", out, "--weights", random_weights, "--quiet")
    assert code == 0, text
    assert sorted(p.name for p in out.iterdir()) == [".colonlight.lock", "manifest.json", "seq", "site 2", "site1"]
    assert len(list((out / "site1" / "p7" / "frames").glob("*.png"))) == 36  # 2 s at 18 fps
    assert len(list((out / "site 2" / "clip ü" / "frames").glob("*.png"))) == 18
    assert len(list((out / "seq" / "frames").glob("*.png"))) == 12
    g = json.loads((out / "site1" / "p7" / "gammas.json").read_text())
    assert {"clip", "source", "fps", "method", "model", "parameters", "colonlight_version", "frames"} <= g.keys()
    assert g["clip"] == "site1/p7" and g["fps"] == 18.0 and g["method"] == "rnn"
    assert g["model"]["name"] == "random-test" and len(g["model"]["sha256"]) == 64
    assert g["parameters"]["model_size"] == 64  # the size these weights' card says they were trained at
    assert [f["index"] for f in g["frames"]] == list(range(36))
    assert g["frames"][0]["gamma"] == 1.0 and g["frames"][1]["gamma"] == 1.0
    assert g["frames"][5]["time_s"] == pytest.approx(5 / 18, abs=1e-6)
    assert g["frames"][5]["source_time_s"] == pytest.approx(0.28)  # source frame 7 of 25 fps
    assert all(0.125 <= f["gamma"] <= 4 for f in g["frames"])
    manifest = json.loads((out / "manifest.json").read_text())
    assert {c["clip"]: (c["status"], c["frames"]) for c in manifest["clips"]} == {
        "seq": ("done", 12),
        "site 2/clip ü": ("done", 18),
        "site1/p7": ("done", 36),
    }


def test_direct_arguments_are_named_by_their_own_name(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    out = tmp_path / "out"
    code, text = invoke(
        "enhance", tree / "site1" / "p7.mp4", tree / "seq", "-o", out, "--weights", random_weights, "-q"
    )
    assert code == 0, text
    assert (out / "p7" / "gammas.json").is_file() and (out / "seq" / "gammas.json").is_file()


def test_every_frame_video_and_jpeg(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    out = tmp_path / "out"
    code, text = invoke(
        "enhance",
        tree / "site1" / "p7.mp4",
        "-o",
        out,
        "--weights",
        random_weights,
        "--fps",
        "0",
        "--video",
        "--format",
        "jpg",
        "-q",
    )
    assert code == 0, text
    assert len(list((out / "p7" / "frames").glob("*.jpg"))) == 50
    with av.open(str(out / "p7" / "enhanced.mp4")) as c:
        s = c.streams.video[0]
        assert s.codec_context.name == "h264" and s.codec_context.pix_fmt == "yuv420p"
        assert sum(1 for _ in c.decode(video=0)) == 50
        assert abs(float(s.average_rate) - 25.0) < 0.01  # read while open: PyAV 18.1.1 refuses a closed one's


def test_video_only(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    out = tmp_path / "out"
    code, text = invoke("enhance", tree / "seq", "-o", out, "--weights", random_weights, "--no-frames", "--video", "-q")
    assert code == 0, text
    assert not (out / "seq" / "frames").exists() or not any((out / "seq" / "frames").iterdir())
    with av.open(str(out / "seq" / "enhanced.mp4")) as c:
        assert sum(1 for _ in c.decode(video=0)) == 12


def test_method_none_is_identity_on_frames(tree: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    code, text = invoke("enhance", tree / "seq", "-o", out, "--method", "none", "-q")
    assert code == 0, text
    import cv2

    src = sorted((tree / "seq").glob("*.png"), key=lambda p: int(p.stem[5:]))
    for i, p in enumerate(src):
        a = cv2.imread(str(p))
        b = cv2.imread(str(out / "seq" / "frames" / f"{i:06d}.png"))
        assert np.array_equal(a, b)
    g = json.loads((out / "seq" / "gammas.json").read_text())
    assert g["model"] is None and all(f["gamma"] == 1.0 for f in g["frames"])


def test_pattern_filter(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    out = tmp_path / "out"
    code, text = invoke("enhance", tree, "-o", out, "--weights", random_weights, "--pattern", "*.mp4", "-q")
    assert code == 0, text
    assert [p.name for p in out.iterdir() if p.is_dir()] == ["site1"]


def test_bad_inputs_are_reported_and_the_rest_completes(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    bad = tree / "bad"
    bad.mkdir()
    zero_byte_file(bad / "empty.mp4")
    text_file(bad / "letter.mp4")
    truncated_copy(tree / "site1" / "p7.mp4", bad / "cut.mp4", keep=0.5)
    make_clip(bad / "single.mp4", n_frames=1, fps=25)
    make_image_folder(bad / "mixed", n=3, size=(64, 48))
    make_image_folder(bad / "mixed", n=1, size=(32, 32), name="z{i}")
    os.symlink(tree / "does-not-exist.mp4", bad / "dangling.mp4")
    out = tmp_path / "out"
    code, text = invoke("enhance", tree, "-o", out, "--weights", random_weights, "-q")
    assert code == 1
    assert "Traceback" not in text
    manifest = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    failed = {k for k, c in manifest.items() if c["status"] == "failed"}
    assert failed == {"bad/empty", "bad/letter", "bad/cut", "bad/single", "bad/mixed", "bad/dangling"}
    for name in failed:
        err = manifest[name]["error"]
        assert "\n" not in err and Path(name).name in err, err
        assert not (out / name / "gammas.json").exists()
    assert "only 1 frame" in manifest["bad/single"]["error"] or "too short" in manifest["bad/single"]["error"]
    for good in ("site1/p7", "site 2/clip ü", "seq"):
        assert manifest[good]["status"] == "done"
    error_lines = [ln for ln in text.splitlines() if ln.startswith("failed")]
    assert len(error_lines) == 6


@pytest.mark.skipif(os.geteuid() == 0, reason="root reads files whatever their permissions")
def test_unreadable_file(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    p = tree / "site1" / "p7.mp4"
    p.chmod(0)
    try:
        code, text = invoke("enhance", p, "-o", tmp_path / "out", "--weights", random_weights, "-q")
    finally:
        p.chmod(0o644)
    assert code == 1 and "p7.mp4" in text


def test_path_vanishing_mid_run(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    from colonlight.batch import MethodSpec, discover_clips, run_batch
    from colonlight.pipeline import ClipOptions

    jobs = discover_clips([tree / "site1" / "p7.mp4", tree / "site 2" / "clip ü.mov"], tmp_path / "out")

    def progress(event: str, clip: str, data: dict[str, object]) -> None:
        if event == "start" and clip == "p7":
            (tree / "site 2" / "clip ü.mov").unlink()

    outcomes = run_batch(
        jobs,
        MethodSpec.of("rnn", weights=str(random_weights), device="cpu"),
        ClipOptions(),
        tmp_path / "out",
        progress=progress,
    )
    assert [o.status for o in outcomes] == ["done", "failed"]
    assert "clip ü.mov" in (outcomes[1].error or "")


def test_resume_skips_complete_and_overwrite_redoes(tree: Path, tmp_path: Path, random_weights: Path) -> None:
    out = tmp_path / "out"
    args = ("enhance", tree, "-o", out, "--weights", random_weights, "-q")
    assert invoke(*args)[0] == 0
    before = output_bytes(out)
    code, text = invoke(*args)
    assert code == 0 and sum(ln.startswith("skipped ") for ln in text.splitlines()) == 3
    assert output_bytes(out) == before
    code, text = invoke(*args, "--overwrite")
    assert code == 0 and not any(ln.startswith("skipped ") for ln in text.splitlines())
    assert output_bytes(out) == before
    code, text = invoke("enhance", tree, "-o", out, "--weights", random_weights, "-q", "--format", "jpg")
    assert code == 0 and not any(ln.startswith("skipped ") for ln in text.splitlines())  # other settings: redone
    assert not list(out.rglob("*.png"))


def test_usage_errors_exit_2(tree: Path, tmp_path: Path) -> None:
    assert invoke("enhance", tree, "-o", tmp_path / "o", "--method", "magic")[0] == 2
    assert invoke("enhance", tree, "-o", tmp_path / "o", "--format", "gif")[0] == 2
    assert invoke("enhance", "-o", tmp_path / "o")[0] == 2
    import torch

    if not torch.cuda.is_available():
        code, text = invoke("enhance", tree, "-o", tmp_path / "o", "--device", "cuda:0", "--method", "rnn")
        assert code == 2 and "no CUDA GPU" in text


def test_missing_input_is_a_failed_clip(tmp_path: Path, random_weights: Path) -> None:
    code, text = invoke("enhance", tmp_path / "nope.mp4", "-o", tmp_path / "o", "--weights", random_weights, "-q")
    assert code == 1 and "nope.mp4" in text and "Traceback" not in text


def test_version_and_info() -> None:
    code, text = invoke("--version")
    assert code == 0 and text.startswith("colonlight ")
    code, text = invoke("info", "--json")
    assert code == 0
    info = json.loads(text)
    assert "rnn" in info["methods"] and "torch" in info["versions"]


@pytest.mark.parametrize("kill_after_files", [1, 25, 60])
def test_kill_9_then_rerun_is_byte_identical(tmp_path: Path, random_weights: Path, kill_after_files: int) -> None:
    """Kill a real run with SIGKILL at different moments; rerunning completes it, byte for byte as a clean run."""
    src = tmp_path / "videos"
    for i in range(3):
        make_clip(src / f"c{i}.mp4", n_frames=75, fps=30, size=(256, 192))
    cmd = colonlight_command("enhance", src, "--weights", random_weights, "--video", "-q", "--workers", "1")
    clean = tmp_path / "clean"
    subprocess.run([*cmd, "-o", str(clean)], check=True, capture_output=True, timeout=300)

    out = tmp_path / "killed"
    proc = subprocess.Popen([*cmd, "-o", str(out)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and proc.poll() is None:
        if sum(1 for _ in out.rglob("*.png")) >= kill_after_files:
            break
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    rerun = subprocess.run([*cmd, "-o", str(out)], capture_output=True, text=True, timeout=300)
    assert rerun.returncode == 0, rerun.stderr
    assert not [p for p in out.rglob("*") if "colonlight-tmp" in p.name]
    assert output_bytes(out) == output_bytes(clean)
    shutil.rmtree(out)


# ------------------------------------------------------------------------- the pipeline's threads (enhance_clip)


def _frame_bytes(clip_dir: Path) -> list[bytes]:
    return [p.read_bytes() for p in sorted((clip_dir / "frames").iterdir())]


@pytest.mark.parametrize("fmt", ["png", "jpg"])
def test_pipeline_writes_what_the_methods_push_returns(tmp_path: Path, random_weights: Path, fmt: str) -> None:
    """Decoded in one thread, enhanced in another, encoded by a pool and renamed in order: the frames are the
    bytes of encoding what the method's own stream.push returns, in order, and the gammas are its gammas."""
    from colonlight.frames import encode_image
    from colonlight.methods import create_method
    from colonlight.pipeline import ClipOptions, enhance_clip, iter_enhanced
    from colonlight.video import iter_video_frames

    clip = make_clip(tmp_path / "c.mp4", n_frames=40, fps=30, size=(200, 150))
    for name, options in (("rnn", {"weights": str(random_weights), "device": "cpu"}), ("gamma", {"gamma": 0.7})):
        method = create_method(name, **options)
        out = tmp_path / f"out-{name}-{fmt}"
        enhance_clip(clip, out, method, ClipOptions(format=fmt))
        frames = (f.image for f in iter_video_frames(clip, 18))
        expected = [encode_image(r.frame, fmt, 95) for r in iter_enhanced(frames, create_method(name, **options))]
        assert _frame_bytes(out) == expected, name
        gammas = [f["gamma"] for f in json.loads((out / "gammas.json").read_text())["frames"]]
        pushed = iter_enhanced((f.image for f in iter_video_frames(clip, 18)), create_method(name, **options))
        assert gammas == [r.gamma for r in pushed]


def _record_renames(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Names of the frames renamed into place, in the order the renames happen."""
    import colonlight.atomic

    renamed: list[str] = []
    real = os.replace

    def replace(src: object, dst: object) -> None:
        real(src, dst)  # type: ignore[arg-type]
        if Path(str(dst)).parent.name == "frames":
            renamed.append(Path(str(dst)).name)

    monkeypatch.setattr(colonlight.atomic.os, "replace", replace)
    return renamed


def test_frames_are_published_in_order_whatever_order_the_pool_encodes_them(
    tmp_path: Path, random_weights: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from colonlight import pipeline
    from colonlight.methods import create_method

    real_encode = pipeline.encode_image

    def uneven_encode(rgb: np.ndarray, fmt: str = "png", quality: int = 95) -> bytes:
        data = real_encode(rgb, fmt, quality)
        time.sleep(0.03 if int(rgb.sum()) % 3 == 0 else 0.0)  # some frames finish after later ones
        return data

    monkeypatch.setattr(pipeline, "encode_image", uneven_encode)
    renamed = _record_renames(monkeypatch)
    clip = make_clip(tmp_path / "c.mp4", n_frames=60, fps=30, size=(96, 64))
    method = create_method("rnn", weights=str(random_weights), device="cpu")
    res = pipeline.enhance_clip(clip, tmp_path / "out", method, pipeline.ClipOptions(format="jpg"))
    assert res.frames == 36
    assert renamed == [f"{i:06d}.jpg" for i in range(36)]


@pytest.mark.parametrize("method_name", ["rnn", "gamma"])
def test_a_failing_frame_leaves_a_gap_free_prefix_and_no_temporaries(
    tmp_path: Path, random_weights: Path, monkeypatch: pytest.MonkeyPatch, method_name: str
) -> None:
    """A frame that cannot be encoded stops the clip: the frames published were 000000..k for some k before it
    (never a hole), and once it failed they are removed with it (nothing half-written): no frame, no temporary
    file, no gammas.json, no folder; the error is the real one."""
    from colonlight import pipeline
    from colonlight.methods import create_method

    real_encode = pipeline.encode_image
    calls = {"n": 0}
    lock = threading.Lock()

    def failing_encode(rgb: np.ndarray, fmt: str = "png", quality: int = 95) -> bytes:
        with lock:
            calls["n"] += 1
            n = calls["n"]
        if n == 12:
            raise OSError("disk full (simulated)")
        time.sleep(0.002 * (n % 4))
        return real_encode(rgb, fmt, quality)

    monkeypatch.setattr(pipeline, "encode_image", failing_encode)
    renamed = _record_renames(monkeypatch)
    clip = make_clip(tmp_path / "c.mp4", n_frames=60, fps=30, size=(96, 64))
    options = {"weights": str(random_weights), "device": "cpu"} if method_name == "rnn" else {"gamma": 0.7}
    out = tmp_path / "out"
    with pytest.raises(OSError, match="simulated"):
        pipeline.enhance_clip(clip, out, create_method(method_name, **options), pipeline.ClipOptions(format="png"))
    assert renamed == [f"{i:06d}.png" for i in range(len(renamed))]  # published in order, never a hole
    assert len(renamed) < 12 + pipeline._WRITERS  # never past the frame that failed (the 12th encoded)
    assert not out.exists()  # what it had published is gone with the folder it made


def test_an_abort_from_the_method_stops_the_writers_cleanly(
    tmp_path: Path, random_weights: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An error on the main thread (here: the network) mid-clip: frames already queued may still land, in order;
    nothing half-written, no temporaries, no gammas.json; a rerun completes the clip byte-identically."""
    from colonlight import pipeline
    from colonlight.methods import create_method
    from colonlight.methods.rnn import RecurrentGammaStream

    clip = make_clip(tmp_path / "c.mp4", n_frames=60, fps=30, size=(96, 64))
    options = {"weights": str(random_weights), "device": "cpu"}
    clean = tmp_path / "clean"
    pipeline.enhance_clip(clip, clean, create_method("rnn", **options))

    real_predict = RecurrentGammaStream.predict
    seen = {"n": 0}

    def predict_then_fail(self: RecurrentGammaStream, frame: np.ndarray) -> list[float]:
        seen["n"] += 1
        if seen["n"] == 20:
            raise KeyboardInterrupt
        return real_predict(self, frame)

    monkeypatch.setattr(RecurrentGammaStream, "predict", predict_then_fail)
    out = tmp_path / "out"
    with pytest.raises(KeyboardInterrupt):
        pipeline.enhance_clip(clip, out, create_method("rnn", **options))
    names = sorted(p.name for p in (out / "frames").iterdir())
    assert names == [f"{i:06d}.png" for i in range(len(names))] and len(names) <= 19
    assert not [p for p in out.rglob("*") if "colonlight-tmp" in p.name]
    assert not (out / "gammas.json").exists()
    monkeypatch.undo()
    pipeline.enhance_clip(clip, out, create_method("rnn", **options))
    assert tree_bytes(out) == tree_bytes(clean)
