"""A seventh hostile-input sweep of the engine, on real files and the Python API.

* A frame folder holding one entry named like a frame that is a link loop (``0003.png -> 0003.png``) was dropped
  from a batch without a line: ``DirEntry.is_file`` raises ELOOP, which made the whole folder "cannot list
  folder", so it was not a clip and the walk found nothing in it; named alone it was "no clips found". A dangling
  link or a FIFO named ``0003.png`` was dropped from the clip without a word, every later frame a place earlier
  in times.txt. Each is now the clip's one failed line naming the entry, and the FIFO is never opened.
* ``--model-size ²`` (a superscript: ``str.isdigit`` takes it, ``int`` refuses it) or 5000 digits ended
  ``colonlight enhance`` with a ValueError traceback; ``--device cuda:²`` too. Both are now the options' own
  messages (the service's side is tests/service/test_service_hostile_sweep7.py).
* The Python API's options of the wrong type failed deep or not at all: ``create_method("gamma", gamma=10**400)``
  an OverflowError, ``gamma=None`` "float() argument must be ...", ``create_method("rnn", tone_match="0.5")``
  "'<=' not supported between instances of 'float' and 'str'", ``device=5`` "'int' object has no attribute
  'strip'", ``tone_match=True`` and ``model_size=True`` were taken as 1, ``model_size=64.7`` as 64, ``seeds=nan``
  as NaN; zerodce's ``max_side=nan`` and zerodce++'s ``scale=inf`` raised from ``int()``; CLAHE's
  ``tile_grid=(10000, 10000)`` asked OpenCV for 25 GB ("cv2.error: Insufficient memory") and ``tile_grid=8`` was
  "'int' object is not iterable"; ``enhance_frames(frames, None)`` "'NoneType' object has no attribute 'stream'".
  Each is now an OptionError (a ValueError) or TypeError naming the option.
* ``OUT/manifest.json`` or a clip's ``gammas.json`` that is a FIFO hung ``colonlight enhance`` for ever, without
  a line (the resume reads them), as did ``--camera FIFO``; :func:`colonlight.atomic.read_regular_file` now
  refuses what is no regular file without waiting on it.
* A path with a name past NAME_MAX (``-o`` of 300 characters, ``-w`` or ``colonlight stream`` of one) ended the
  command with "OSError: [Errno 36] File name too long" and a traceback: ``Path.exists`` and ``is_file`` raise
  it. Each is now one line (``prepare_output``, ``load_weights``, the live source and output); ``-o
  dangling-link/out`` said "the output path is a file" and now names the dangling parent.
* OpenCV's "[ERROR:...] imencode(): can't encode data ... Maximum supported image dimension is 65500 pixels" on
  stderr, beside "OpenCV could not encode a 70000x1 frame as jpg": frames too wide for JPEG now say so.
* ``ClipOptions(fps=np.float32(18))`` ended ``run_batch`` with "Object of type float32 is not JSON serializable".
* ``ClipOptions(folder_fps=nan)`` (or -5, or 1e308) was taken, and ``enhance_clip`` of a frame folder wrote
  ``nan`` (or negative, or all-zero) times into times.txt and NaN into gammas.json; ``fps="18"`` was a TypeError
  of ``<=``, ``max_pixels=nan`` a ValueError of ``int()`` once the clip ran, ``quality=95.5`` was recorded as it was.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

import colonlight
from colonlight import ClipOptions, MethodSpec, create_method, discover, run_batch
from colonlight.errors import DeviceError, InputError, OptionError
from colonlight.frames import iter_image_folder

from ..commands import run_colonlight
from ..media import flat_png, make_clip, needs_ffmpeg

BROKEN = {
    "loop": ("symbolic link loop", lambda p: os.symlink(p.name, p)),
    "dangling": ("not found (a dangling link", lambda p: os.symlink("nowhere.png", p)),
    "fifo": ("not a regular file (a FIFO", os.mkfifo),
}


def _frames(folder: Path, n: int = 3) -> Path:
    folder.mkdir(parents=True)
    for i in range(n):
        (folder / f"{i:04d}.png").write_bytes(flat_png(64, 48, level=40 * i))
    return folder


@pytest.mark.timeout(60)  # a FIFO opened for reading would wait forever
@pytest.mark.parametrize("kind", list(BROKEN))
def test_a_frame_that_is_no_file_fails_its_folder_in_one_line(tmp_path: Path, kind: str) -> None:
    says, make = BROKEN[kind]
    inputs = tmp_path / "in"
    good = _frames(inputs / "good")
    bad = _frames(inputs / "bad")
    make(bad / "0003.png")
    with pytest.raises(InputError) as err:
        list(iter_image_folder(bad))
    assert str(err.value).startswith(f"{bad / '0003.png'}: not a frame image: {says}"), err.value
    # the batch: the folder is a clip that fails naming the entry, the other folder is done
    found = discover([inputs], tmp_path / "out")
    assert sorted(j.name for j in found.jobs) == ["bad", "good"] and found.problems == []
    outcomes = run_batch(found.jobs, MethodSpec.of("gamma"), ClipOptions(), tmp_path / "out")
    status = {o.name: (o.status, o.error) for o in outcomes}
    assert status["good"] == ("done", None)
    assert status["bad"][0] == "failed" and f"{bad / '0003.png'}: not a frame image: {says}" in str(status["bad"][1])
    assert not (tmp_path / "out" / "bad").exists()
    assert len(list((tmp_path / "out" / "good" / "frames").iterdir())) == len(list(good.iterdir()))


def test_a_folder_inside_a_frame_folder_is_still_ignored(tmp_path: Path) -> None:
    folder = _frames(tmp_path / "f")
    (folder / "0005.png").mkdir()  # a folder named like a frame: sub-folders are not frames (as before)
    assert [f.index for f in iter_image_folder(folder)] == [0, 1, 2]


@needs_ffmpeg
@pytest.mark.timeout(120)
@pytest.mark.parametrize(
    ("flag", "value", "says"),
    [
        ("--model-size", "²", "model_size must be an integer 8..1024, 'full' or 'auto', got '²'"),
        ("--model-size", "1" * 5000, "model_size must be an integer 8..1024, 'full' or 'auto', got '1111"),
        ("--device", "cuda:²", "expected cuda or cuda:N with N a number"),
    ],
    ids=["superscript-size", "5000-digit-size", "superscript-device"],
)
def test_cli_numbers_int_refuses_are_one_usage_line(tmp_path: Path, flag: str, value: str, says: str) -> None:
    clip = make_clip(tmp_path / "a.mp4", 4, size=(64, 48))
    code, output = run_colonlight("enhance", str(clip), "-o", str(tmp_path / "out"), "-q", flag, value)  # no traceback
    assert "int()" not in output and "4300" not in output, output
    assert code == 2, output
    assert says in " ".join(output.replace("│", " ").split()), output
    assert not (tmp_path / "out" / "a").exists()


@pytest.mark.parametrize(
    ("method", "options", "says"),
    [
        ("gamma", {"gamma": 10**400}, "gamma must be finite and > 0, got 1000"),
        ("gamma", {"gamma": None}, "gamma must be finite and > 0, got None"),
        ("gamma", {"gamma": True}, "gamma must be finite and > 0, got True"),
        ("agcwd", {"alpha": [0.5]}, "alpha must be finite and > 0, got [0.5]"),
        ("clahe", {"clip_limit": 10**400}, "clip_limit must be finite and >= 0"),
        ("clahe", {"tile_grid": (10000, 10000)}, "tile_grid must be two integers 1..256, got (10000, 10000)"),
        ("clahe", {"tile_grid": 8}, "tile_grid must be two integers 1..256, got 8"),
        ("clahe", {"tile_grid": (8.5, 8)}, "tile_grid must be two integers 1..256, got (8.5, 8)"),
        ("rnn", {"tone_match": "0.5x"}, "tone_match must be within 0..1, got '0.5x'"),
        ("rnn", {"tone_match": True}, "tone_match must be within 0..1, got True"),
        ("rnn", {"scene_cut": 10**400}, "scene_cut must be within 0..1"),
        ("rnn", {"model_size": True}, "model size must be a positive integer, 'full' or 'auto', got True"),
        ("rnn", {"model_size": 64.7}, "model size must be a positive integer, 'full' or 'auto', got 64.7"),
        ("rnn", {"seeds": float("nan")}, "seeds must be a whole number >= 0, got nan"),
        ("rnn", {"seeds": "2"}, "seeds must be a whole number >= 0, got '2'"),
        ("zerodce", {"max_side": float("nan")}, "max_side must be a positive integer or None, got nan"),
        ("zerodce++", {"scale": float("inf")}, "scale must be a positive integer, got inf"),
    ],
)
def test_a_method_option_of_the_wrong_type_names_the_option(method: str, options: dict, says: str) -> None:
    with pytest.raises(OptionError) as err:
        create_method(method, **options)
    assert str(err.value).startswith(says), err.value
    assert isinstance(err.value, ValueError)


def test_options_of_the_right_kinds_are_still_taken() -> None:
    assert create_method("gamma", gamma=np.float32(0.5)).gamma == 0.5
    assert create_method("gamma", gamma="0.5").gamma == 0.5
    assert create_method("clahe", tile_grid=(np.int64(4), 4.0)).tile_grid == (4, 4)
    rnn = create_method("rnn", model_size=np.int64(32), tone_match=np.float32(0.25), scene_cut=1, seeds=np.int64(1))
    assert (rnn.model_size, rnn.tone_match, rnn.scene_cut, rnn.seeds) == (32, 0.25, 1.0, 1)
    assert create_method("rnn", model_size=64.0).model_size == 64


@pytest.mark.parametrize("device", [5, "cuda:²", "cuda:" + "1" * 5000])
def test_a_device_that_is_no_device_name_is_a_device_error(device: object) -> None:
    with pytest.raises(DeviceError, match="device"):
        colonlight.resolve_device(device)  # type: ignore[arg-type]


@pytest.mark.parametrize("method", [None, 5])
def test_enhance_frames_with_no_method_is_a_type_error(method: object) -> None:
    frame = np.zeros((8, 8, 3), np.uint8)
    with pytest.raises(TypeError, match="method must be a Method or a method's name, got "):
        list(colonlight.enhance_frames([frame], method))  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("options", "says"),
    [
        ({"folder_fps": float("nan")}, "folder_fps must be within 1/1001..240, got nan"),
        ({"folder_fps": -5}, "folder_fps must be within 1/1001..240, got -5"),
        ({"folder_fps": 1e308}, "folder_fps must be within 1/1001..240, got 1e+308"),
        ({"folder_fps": 0}, "folder_fps must be within 1/1001..240, got 0"),
        ({"fps": "18"}, "fps must be 0 or within 1/1001..240, got '18'"),
        ({"fps": True}, "fps must be 0 or within 1/1001..240, got True"),
        ({"max_pixels": float("nan")}, "max_pixels must be a whole number >= 1, got nan"),
        ({"max_gap_frames": None}, "max_gap_frames must be a whole number >= 1, got None"),
        ({"quality": 95.5}, "quality must be within 1..100, got 95.5"),
    ],
)
def test_clip_options_of_the_wrong_type_or_no_rate_are_option_errors(tmp_path: Path, options: dict, says: str) -> None:
    with pytest.raises(OptionError) as err:
        ClipOptions(**options)
    assert str(err.value) == says
    assert ClipOptions(fps=np.float32(18), folder_fps=25, max_pixels=np.int64(4096), quality=90.0).folder_fps == 25


@needs_ffmpeg
@pytest.mark.timeout(60)  # before: each of these waited forever for a writer to the FIFO
def test_a_fifo_where_the_batch_reads_its_records_is_not_waited_on(tmp_path: Path) -> None:
    """``OUT/manifest.json`` or ``OUT/a/gammas.json`` a FIFO: ``colonlight enhance`` hung without a word (the
    resume read them). Neither is a record now: the clip is done and real files take their places."""
    clip = make_clip(tmp_path / "a.mp4", 4, size=(64, 48))
    out = tmp_path / "out"
    (out / "a").mkdir(parents=True)
    os.mkfifo(out / "manifest.json")
    os.mkfifo(out / "a" / "gammas.json")
    outcomes = run_batch(discover([clip], out).jobs, MethodSpec.of("gamma"), ClipOptions(), out)
    assert [(o.status, o.skipped) for o in outcomes] == [("done", False)]
    assert colonlight.read_json(out / "manifest.json")["clips"][0]["status"] == "done"
    assert colonlight.read_json(out / "a" / "gammas.json")["frame_count"] == outcomes[0].frames


@pytest.mark.timeout(60)
def test_a_camera_file_that_is_a_fifo_is_one_line_not_a_wait(tmp_path: Path) -> None:
    os.mkfifo(tmp_path / "cameras.txt")
    with pytest.raises(InputError) as err:
        colonlight.read_camera(tmp_path / "cameras.txt")
    assert str(err.value) == (
        f"{tmp_path / 'cameras.txt'}: cannot read the camera file (not a regular file (a FIFO, socket or device))"
    )
    (tmp_path / "dso.txt").write_bytes(b"Pinhole 0.5 0.5 0.5 0.5 0\r\n128 96\r\ncrop\r\n128 96\r\n")
    assert "\r" not in colonlight.read_camera(tmp_path / "dso.txt").text  # newlines as read_text gave them


@needs_ffmpeg
def test_clip_options_of_numpy_numbers_run_a_batch(tmp_path: Path) -> None:
    """An np.float32 fps ended ``run_batch`` with "Object of type float32 is not JSON serializable" (the
    manifest) and failed ``enhance_clip`` in ``Fraction()``; an np.int64 quality failed at gammas.json."""
    clip = make_clip(tmp_path / "a.mp4", 4, size=(64, 48))
    opts = ClipOptions(fps=np.float32(18), quality=np.int64(90), format="jpg", max_pixels=np.int64(10**7))
    assert (type(opts.fps), type(opts.quality), type(opts.max_pixels)) == (float, int, int)
    found = discover([clip], tmp_path / "out")
    outcomes = run_batch(found.jobs, MethodSpec.of("gamma"), opts, tmp_path / "out")
    assert [(o.status, o.error) for o in outcomes] == [("done", None)]
    result = colonlight.enhance_clip(clip, tmp_path / "one", create_method("gamma"), opts)
    assert result.frames == len(list((tmp_path / "one" / "frames").iterdir())) > 0


def test_a_folder_rate_that_is_no_rate_writes_no_times(tmp_path: Path) -> None:
    """``clip_frames`` (the API under ``enhance_clip``) refuses it too: NaN times are written nowhere."""
    folder = _frames(tmp_path / "f")
    for rate in (float("nan"), -5.0, float("inf")):
        with pytest.raises(OptionError, match="the rate of a folder of frames must be"):
            list(colonlight.clip_frames(folder, folder_fps=rate))
    assert [f.time_s for f in colonlight.clip_frames(folder, folder_fps=10.0)] == [0.0, 0.1, 0.2]


def test_frames_too_wide_for_jpeg_fail_in_one_line_without_opencv_noise(
    tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    """70000x1 frames (0.07 Mpx, well within the pixel cap) as ``--format jpg``: OpenCV printed "[ERROR:...]
    imencode(): can't encode data ... Maximum supported image dimension is 65500 pixels" once per writer thread,
    beside "OpenCV could not encode a 70000x1 frame as jpg", which gave no cause. PNG holds them."""
    wide = tmp_path / "in" / "wide"
    wide.mkdir(parents=True)
    for i in range(2):
        (wide / f"{i}.png").write_bytes(flat_png(70000, 1, level=60 * i))
    out = tmp_path / "out"
    jobs = discover([tmp_path / "in"], out).jobs
    (failed,) = run_batch(jobs, MethodSpec.of("gamma"), ClipOptions(format="jpg"), out)
    assert failed.status == "failed"
    assert failed.error == f"{wide}: JPEG holds at most 65500 pixels a side, the frames are 70000x1: write them as png"
    assert not (out / "wide").exists()
    assert "ERROR" not in capfd.readouterr().err
    (done,) = run_batch(jobs, MethodSpec.of("gamma"), ClipOptions(format="png"), out)
    assert (done.status, done.frames) == ("done", 2)
    with pytest.raises(ValueError, match="at least one pixel"):
        colonlight.encode_image(np.zeros((0, 4, 3), np.uint8))  # cvtColor's assertion before


def test_paths_with_a_name_too_long_are_one_line(tmp_path: Path) -> None:
    from colonlight.checkpoint import load_weights
    from colonlight.errors import CheckpointError
    from colonlight.live import parse_source, prepare_output_dir
    from colonlight.outdir import OutputError, prepare_output

    long = tmp_path / ("x" * 300)  # past NAME_MAX (255)
    for path in (long, long / "out"):
        with pytest.raises(OutputError, match="cannot use the output path: File name too long$"):
            prepare_output(path)
        with pytest.raises(InputError, match="cannot use the output folder: File name too long$"):
            prepare_output_dir(path, overwrite=False)
    with pytest.raises(CheckpointError, match=r"cannot read the checkpoint file \(File name too long\)$"):
        load_weights(long)
    with pytest.raises(InputError, match="cannot open: File name too long$"):
        parse_source(str(long) + ".mp4")
    os.symlink("nowhere", tmp_path / "dangling")
    with pytest.raises(OutputError, match="dangling/out: a parent of the output folder is a dangling symbolic link$"):
        prepare_output(tmp_path / "dangling" / "out")
    assert list(tmp_path.iterdir()) == [tmp_path / "dangling"]


@pytest.mark.parametrize("value", [10**400, None, "x", float("nan"), -1.0, 0])
def test_a_lookup_table_of_no_usable_exponent_names_it(value: object) -> None:
    """``gamma_lut(10**400)`` or ``(None)`` failed in numpy's ``isfinite`` with a TypeError naming nothing."""
    from colonlight.curves import gain_gamma_lut, gamma_lut
    from colonlight.errors import OptionError

    with pytest.raises(OptionError, match="^gamma must be finite and > 0, got "):
        gamma_lut(value)  # type: ignore[arg-type]
    with pytest.raises(OptionError, match="^gain must be finite and > 0, got "):
        gain_gamma_lut(value, 1.0)  # type: ignore[arg-type]
    assert np.array_equal(gamma_lut(np.float32(0.5)), gamma_lut(0.5))  # numpy numbers: the same table


def test_weights_that_are_a_fifo_are_named_so(tmp_path: Path) -> None:
    """A FIFO given as the weights read "no such checkpoint file", which sent a user looking for a missing file."""
    from colonlight.checkpoint import load_weights
    from colonlight.errors import CheckpointError

    fifo = tmp_path / "w.safetensors"
    os.mkfifo(fifo)
    with pytest.raises(CheckpointError, match=r"w\.safetensors: not a regular file \(a FIFO, socket or device\)$"):
        load_weights(fifo)


def test_reading_a_folder_as_a_record_says_it_is_a_folder(tmp_path: Path) -> None:
    """``read_regular_file`` refuses what is no regular file; a folder keeps the cause reading one always gave."""
    from colonlight.atomic import read_json

    with pytest.raises(IsADirectoryError, match="Is a directory"):
        read_json(tmp_path)


@pytest.mark.skipif(not Path("/proc/self/mem").is_file(), reason="needs Linux's /proc/self/mem")
def test_weights_whose_read_fails_are_a_checkpoint_error() -> None:
    """A weights file whose read fails (permission denied, an I/O error) was a raw OSError from hashing it: a
    traceback in ``enhance`` and "cannot write" in ``export``, which blamed the output. ``/proc/self/mem`` is a
    regular file whose read at offset 0 fails with EIO, whoever runs the test (root reads any mode)."""
    from colonlight.checkpoint import load_weights
    from colonlight.errors import CheckpointError

    with pytest.raises(CheckpointError, match=r"^/proc/self/mem: cannot read the checkpoint file \(.+\)$"):
        load_weights("/proc/self/mem")
