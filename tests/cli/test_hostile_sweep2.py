"""A second hostile-input sweep of the CLI (not ``stream`` or ``serve``), through real ``colonlight`` processes on
real files: absurd option values (a pixel cap past libavcodec's int range, an fps that rounds to 0, NaN and
infinite training numbers, renders of 100000 pixels a side, negative seeds), model cards that are valid JSON but
not a card, outputs that are files, and output folder names too long for the file system. Each is a usage error
or one line naming the file and the cause, never a traceback; the rest of the batch goes on."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from ..commands import run_colonlight
from ..media import make_clip, needs_ffmpeg

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

NONE = ("--method", "none", "-q", "-j", "1")
SHIPPED = Path(__file__).resolve().parents[2] / "colonlight" / "weights" / "colonlight-rnn"


@pytest.fixture(scope="module")
def videos(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("videos")
    make_clip(d / "a.mp4", 12, first_index=0)
    make_clip(d / "b.mp4", 12, first_index=100)
    return d


def test_a_pixel_cap_past_libavcodecs_int_range_still_decodes(videos: Path, tmp_path: Path) -> None:
    """``--max-pixels`` above INT_MAX went to libavcodec's ``max_pixels`` (an int option) as it was: refused
    there, every frame of every clip was refused too, and each clip failed as "no decodable video frames"."""
    out = tmp_path / "out"
    code, output = run_colonlight("enhance", str(videos), "-o", str(out), "--max-pixels", str(10**12), *NONE)
    assert code == 0, output
    entries = json.loads((out / "manifest.json").read_text())["clips"]
    assert sorted((e["clip"], e["status"]) for e in entries) == [("a", "done"), ("b", "done")]


def test_an_fps_that_rounds_to_zero_is_a_usage_error(videos: Path, tmp_path: Path) -> None:
    """``--fps 1e-9`` passed the 0..240 check, then rounded to 0 (rates are ratios with a denominator of at most
    1001) and failed every clip with "frame rate must be positive, got 1e-09"."""
    for fps in ("1e-9", "0.0004"):
        out = tmp_path / f"out-{fps}"
        code, output = run_colonlight("enhance", str(videos), "-o", str(out), "--fps", fps, *NONE)
        assert code == 2, output
        assert "--fps" in output and "1/1001" in output, output
        assert not out.exists(), output
    code, output = run_colonlight("enhance", str(videos), "-o", str(tmp_path / "slow"), "--fps", "0.001", *NONE)
    assert code == 1 and "span too short a time for 0.001 fps" in output, output  # accepted, then too short


def test_train_refuses_numbers_no_run_can_use_before_any_work(videos: Path, tmp_path: Path) -> None:
    """NaN or negative ``--fps``, a NaN or negative ``--lr``, an infinite loss weight, a 100000-pixel
    ``--size`` or a negative ``--synthetic-seed`` each ended in a traceback (from ``Fraction``, torch's Adam,
    OpenCV's allocator, numpy's seeding) once training had started; each is a usage error naming its flag."""
    out = tmp_path / "run"
    bad = [
        ("--fps", "nan"),
        ("--fps", "-5"),
        ("--lr", "nan"),
        ("--lr", "0"),
        ("--temporal", "inf"),
        ("--anchor", "nan"),
        ("--size", "100000"),
        ("--synthetic-seed", "-1"),
    ]
    for flag, value in bad:
        code, output = run_colonlight("train", str(videos), "-o", str(out), "--epochs", "1", flag, value)
        assert code == 2, (flag, value, output)
        assert flag in output, (flag, value, output)
        assert not out.exists(), (flag, value, output)


@pytest.mark.parametrize(
    ("card", "says"),
    [
        ([1, 2], "a JSON object expected, found list"),
        ({"input_size": "abc"}, "input_size must be a whole number 8..1024, got 'abc'"),
        ({"input_size": -5}, "input_size must be a whole number 8..1024, got -5"),
        ({"seed_frames": "x"}, "seed_frames must be a whole number"),
    ],
    ids=["list", "size-text", "size-negative", "seeds-text"],
)
def test_a_model_card_that_is_not_a_card_is_one_line(videos: Path, tmp_path: Path, card: object, says: str) -> None:
    """Valid JSON beside valid weights, but not a card: a list raised AttributeError, a size or seed count that
    is no number ValueError (tracebacks), a negative size failed every clip inside OpenCV's resize."""
    weights = tmp_path / "w.safetensors"
    weights.write_bytes(SHIPPED.with_suffix(".safetensors").read_bytes())
    if isinstance(card, dict):
        shipped = json.loads(SHIPPED.with_suffix(".json").read_text())
        shipped.pop("sha256", None)
        card = {**shipped, **card}
    (tmp_path / "w.json").write_text(json.dumps(card))
    out = tmp_path / "out"
    code, output = run_colonlight("enhance", str(videos), "-o", str(out), "-w", str(weights), "-q", "-j", "1")
    assert code == 2, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {tmp_path / 'w.json'}: ") and says in lines[0], output
    assert not (out / "manifest.json").exists()


def test_synth_refuses_absurd_values_and_an_output_that_is_a_file(tmp_path: Path) -> None:
    """``--fps inf`` or ``1e9`` (a smoothing kernel of 10^9 taps), 100000 pixels a side (a 75 GB array) and a
    negative seed ended in tracebacks; an output that is a file in a NotADirectoryError traceback."""
    small = ("--frames", "3", "--width", "64", "--height", "48", "--no-video")
    for flag, value in [("--fps", "inf"), ("--fps", "1e9"), ("--width", "100000"), ("--seed", "-1")]:
        code, output = run_colonlight("synth", str(tmp_path / "s"), *small, flag, value)
        assert code == 2 and flag in output, (flag, value, output)
        assert not (tmp_path / "s").exists()
    afile = tmp_path / "afile"
    afile.write_text("x")
    code, output = run_colonlight("synth", str(afile), *small)
    assert code == 1, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert lines == [f"error: {afile}: cannot write the clips: {afile} is a file, not a folder"], output
    assert afile.read_text() == "x"


def test_evaluate_to_an_output_that_is_a_file_stops_before_any_work(videos: Path, tmp_path: Path) -> None:
    """The output was first written after every clip had been evaluated: a file there was a FileExistsError
    traceback at the end. Now it is a usage error, as in ``enhance``, before anything is computed."""
    from colonlight.evaluation.requirements import missing_extras

    if missing_extras(colmap=False):
        pytest.skip(f"the eval extra is not installed ({', '.join(missing_extras(colmap=False))})")
    afile = tmp_path / "afile"
    afile.write_text("x")
    for out in (afile, afile / "sub"):
        code, output = run_colonlight("evaluate", str(videos), "-o", str(out), "--methods", "none", "--no-colmap", "-q")
        assert code == 2, output
        lines = [line for line in output.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith(f"error: {out}: ") and "file" in lines[0], output
    assert afile.read_text() == "x"


def test_an_output_name_too_long_for_the_file_system_fails_that_clip_alone(tmp_path: Path) -> None:
    """``x/N.mp4`` and ``y/N.mp4`` (N of 251 characters) get ``N-mp4`` (255, the most a name may have) and
    ``N-mp4-2`` (257). The second's failure raised ENAMETOOLONG again while clearing its temporaries, and the
    whole batch ended in a traceback; now that clip fails in one line and the others are done."""
    name = "N" * 251
    first = make_clip(tmp_path / "x" / f"{name}.mp4", 12)
    second = make_clip(tmp_path / "y" / f"{name}.mp4", 12, first_index=50)
    other = make_clip(tmp_path / "z" / "other.mp4", 12, first_index=100)
    for workers in ("1", "2"):
        out = tmp_path / f"out{workers}"
        args = ("--method", "none", "-q", "-j", workers)
        code, output = run_colonlight("enhance", str(first), str(second), str(other), "-o", str(out), *args)
        assert code == 1, output
        failed = [line for line in output.splitlines() if line.startswith("failed")]
        assert len(failed) == 1 and str(second) in failed[0] and "File name too long" in failed[0], output
        entries = {e["clip"]: e["status"] for e in json.loads((out / "manifest.json").read_text())["clips"]}
        assert entries == {f"{name}-mp4": "done", f"{name}-mp4-2": "failed", "other": "done"}, entries
        assert (out / f"{name}-mp4" / "gammas.json").is_file() and (out / "other" / "gammas.json").is_file()
        assert sorted(p.name for p in out.iterdir()) == sorted(
            [".colonlight.lock", "manifest.json", "other", f"{name}-mp4"]
        )


def test_a_cluster_address_without_a_port_is_one_line_at_once(videos: Path, tmp_path: Path) -> None:
    """``--cluster garbage`` (or ``tcp://host`` without its port) got past the address check: Dask's Client
    failed half-made, the error line came, and then its ``__del__`` hung 20 s at exit and printed a traceback."""
    pytest.importorskip("distributed")
    for address in ("garbage", "tcp://host", "tcp://host:port"):
        t0 = time.monotonic()
        code, output = run_colonlight("enhance", str(videos), "-o", str(tmp_path / "out"), "--cluster", address, *NONE)
        assert code == 1, output
        lines = [line for line in output.splitlines() if line.strip()]
        assert lines == [lines[0]] and "is not a Dask scheduler address" in lines[0] and address in lines[0], output
        assert time.monotonic() - t0 < 15, output


def test_weights_that_are_a_folder_say_so(videos: Path, tmp_path: Path) -> None:
    """``-w DIR`` said "no such checkpoint file" of a folder that exists."""
    folder = tmp_path / "weights.safetensors"
    folder.mkdir()
    code, output = run_colonlight("enhance", str(videos), "-o", str(tmp_path / "out"), "-w", str(folder), "-q")
    assert code == 2, output
    assert output.strip() == f"error: {folder}: a folder, not a checkpoint file", output
