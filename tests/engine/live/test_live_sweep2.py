"""Hostile sources and outputs of ``colonlight stream``, second sweep, through the real command: a still image
given as a stream, an output folder that is a file, a pipe to a full device, a frame size that changes under a
pipe, a disk that fills mid-stream, a source killed mid-stream (served by the ffmpeg binary on loopback), a URL
that never answers, and SIGTERM with every output open. The rules: one ``error:`` line naming the input and the
cause, no traceback, and what was written is whole and consistent (every frame file complete, every log line a
whole record, the pipe's frames those of the log)."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import av
import cv2
import pytest

from ...commands import colonlight_env
from ...filesystems import mounted_tmpfs
from ...media import X264, ffmpeg_exe, index_frame, make_clip, make_noise_clip, needs_ffmpeg

pytestmark = [needs_ffmpeg, pytest.mark.timeout(120)]


def _stream(*args: str, stdout: object = subprocess.DEVNULL, stdin: bytes | None = None) -> tuple[int, str]:
    done = subprocess.run(
        [sys.executable, "-m", "colonlight_cli.main", "stream", *args, "-m", "none"],
        env=colonlight_env(),
        input=stdin,
        stdout=stdout,  # type: ignore[arg-type]
        stderr=subprocess.PIPE,
        timeout=90,
    )
    return done.returncode, done.stderr.decode(errors="replace")


def _one_error(err: str, *needles: str) -> str:
    """The one ``error:`` line of ``err`` (no traceback), which contains every needle."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith("error:")]
    assert len(lines) == 1, err
    assert all(n in lines[0] for n in needles), err
    return lines[0]


def _log(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / "gammas.jsonl").read_text().splitlines()]


def _frames(out: Path) -> list[int]:
    """Indices of the frames in OUT/frames, each checked whole (it decodes); no temporaries left."""
    names = sorted(os.listdir(out / "frames"))
    assert not [n for n in names if n.startswith(".")], names
    for n in names:
        assert cv2.imread(str(out / "frames" / n)) is not None, n
    return [int(n.partition(".")[0]) for n in names]


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("sweep2-live")
    small = make_clip(d / "small.ts", 30, 30, (128, 96), codec_args=(*X264, "-g", "15"))
    large = make_clip(d / "large.ts", 30, 30, (160, 120), codec_args=(*X264, "-g", "15"), first_index=30)
    resized = d / "resized.ts"  # MPEG-TS joins byte for byte: 128x96, then 160x120 from source frame 30 on
    resized.write_bytes(small.read_bytes() + large.read_bytes())
    still = d / "still.png"
    cv2.imwrite(str(still), index_frame(7))
    return {
        "small": small,
        "resized": resized,
        "still": still,
        "busy": make_noise_clip(d / "busy.ts", 40, 30, (320, 240)),  # frames of ~230 KB as PNGs
        "live": make_clip(d / "live.ts", 150, 30, (128, 96), codec_args=(*X264, "-g", "15")),
    }


# ---------------------------------------------------------------------------------------------- sources


def test_a_still_image_file_is_refused_by_name(tmp_path: Path, clips: dict[str, Path]) -> None:
    # it was read as a "stream" of one frame that ended at once, unlike `enhance` and the service, which refuse it
    out = tmp_path / "out"
    code, err = _stream(str(clips["still"]), "-o", str(out))
    assert code == 1
    _one_error(err, f"{clips['still']}: not a video", "still image", "(png_pipe)")
    assert not out.exists()


def test_images_piped_on_standard_input_are_still_frames_of_a_stream(tmp_path: Path, clips: dict[str, Path]) -> None:
    out = tmp_path / "out"
    # standard input is a live source, whose default drops the oldest frame when processing falls behind: three
    # images arriving at once on a loaded machine lost the first one. Every frame is asked for here.
    code, err = _stream("-", "-o", str(out), "--fps", "0", "--drop", "never", stdin=clips["still"].read_bytes() * 3)
    assert code == 0, err
    assert _frames(out) == [0, 1, 2] and len(_log(out)) == 3


def test_a_url_that_never_answers_is_one_line_after_the_timeout(tmp_path: Path) -> None:
    with socket.socket() as listener:  # accepts connections (the kernel's backlog) and never says a word
        listener.bind(("127.0.0.1", 0))
        listener.listen(8)
        port = listener.getsockname()[1]
        for url in (f"tcp://127.0.0.1:{port}", f"http://127.0.0.1:{port}/live.ts"):
            t0 = time.monotonic()
            code, err = _stream(url, "-o", str(tmp_path / "out"), "--timeout", "1")
            assert code == 1 and time.monotonic() - t0 < 60
            _one_error(err, f"{url}: cannot open (no data before the timeout)")
    assert not (tmp_path / "out").exists()


def _listening(port: int) -> bool:
    """True once a socket listens on 127.0.0.1:``port`` (read from /proc, without connecting: ffmpeg's HTTP server
    serves one client only)."""
    want = f"0100007F:{port:04X}"
    with contextlib.suppress(OSError):
        for line in Path("/proc/net/tcp").read_text().splitlines()[1:]:
            fields = line.split()
            if fields[1] == want and fields[3] == "0A":
                return True
    return False


def _stream_proc(*args: str, stdout: object, stdin: object = None) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "colonlight_cli.main", "stream", *args, "-m", "none"],
        env=colonlight_env(),
        stdin=stdin,  # type: ignore[arg-type]
        stdout=stdout,  # type: ignore[arg-type]
        stderr=subprocess.PIPE,
    )


def _wait_for_records(out: Path, n: int, proc: subprocess.Popen[bytes]) -> None:
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and proc.poll() is None:
        if (out / "gammas.jsonl").is_file() and len(_log(out)) >= n:
            return
        time.sleep(0.05)
    raise AssertionError(f"fewer than {n} frames out")


@pytest.mark.skipif(not Path("/proc/net/tcp").exists(), reason="needs Linux's /proc/net/tcp")
def test_a_source_killed_mid_stream_ends_the_stream_with_whole_outputs(tmp_path: Path, clips: dict[str, Path]) -> None:
    exe = ffmpeg_exe()
    assert exe is not None
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    url = f"http://127.0.0.1:{port}/live.ts"
    server = subprocess.Popen(
        [exe, "-v", "error", "-nostdin", "-re", "-i", str(clips["live"]), "-c", "copy", "-f", "mpegts"]
        + ["-listen", "1", url],
        stderr=subprocess.DEVNULL,
    )
    out = tmp_path / "out"
    proc: subprocess.Popen[bytes] | None = None
    try:
        deadline = time.monotonic() + 60
        while not _listening(port):
            assert time.monotonic() < deadline and server.poll() is None, "ffmpeg never listened"
            time.sleep(0.05)
        with open(tmp_path / "out.y4m", "wb") as piped:
            proc = _stream_proc(url, "-o", str(out), "--timeout", "3", "--pipe", "y4m", stdout=piped)
            _wait_for_records(out, 5, proc)
            server.kill()  # the source dies: no end of stream, the connection just goes
            _, raw = proc.communicate(timeout=60)
    finally:
        for p in (server, proc):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait(10)
    err = raw.decode(errors="replace")
    assert proc.returncode == 0 and "Traceback" not in err and "ended: source" in err, err
    records = _log(out)
    assert len(records) >= 5 and [r["index"] for r in records] == _frames(out)
    assert json.loads((out / "stream.json").read_text())["summary"]["frames_out"] == len(records)
    y4m = (tmp_path / "out.y4m").read_bytes()
    header, _, _ = y4m.partition(b"\n")
    assert len(y4m) == len(header) + 1 + len(records) * (6 + 128 * 96 * 3 // 2)  # whole frames, one per record


# ---------------------------------------------------------------------------------------------- outputs


def test_an_output_that_is_a_file_is_refused_before_the_stream(tmp_path: Path, clips: dict[str, Path]) -> None:
    # it was a FileExistsError / NotADirectoryError traceback at the first frame
    note = tmp_path / "notes.txt"
    note.write_text("keep me\n")
    for out, needle in ((note, "is a file, not a folder"), (note / "sub", f"lies under {note}, which is a file")):
        code, err = _stream(str(clips["small"]), "-o", str(out))
        assert code == 2  # an unusable --output is a usage error, as in `enhance`
        _one_error(err, f"{out}: {needle}")
        assert "waiting for frames" not in err  # refused before the source is opened
    assert note.read_text() == "keep me\n"


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_pipe_to_a_full_device_is_one_line(tmp_path: Path, clips: dict[str, Path]) -> None:
    # ENOSPC on standard output was an OSError traceback
    out = tmp_path / "out"
    for kind in ("y4m", "mpegts"):
        with open("/dev/full", "wb") as full:
            code, err = _stream(str(clips["small"]), "-o", str(out), "--pipe", kind, "--overwrite", stdout=full)
        assert code == 1
        _one_error(err, f"standard output (--pipe {kind}): cannot write (No space left on device)")
        records = _log(out)
        assert [r["index"] for r in records] == _frames(out)  # the folder and the log agree, whatever they hold
        summary = json.loads((out / "stream.json").read_text())["summary"]
        assert summary["frames_out"] == len(records) and summary["error"]


def test_a_size_change_under_a_pipe_names_the_source_and_the_outputs_agree(
    tmp_path: Path, clips: dict[str, Path]
) -> None:
    # the message did not name the source, and the refused frame still reached the folder (a frame without its
    # log line)
    src = clips["resized"]
    for kind in ("y4m", "mpegts"):
        out, piped = tmp_path / f"out-{kind}", tmp_path / f"piped.{kind}"
        with open(piped, "wb") as fh:
            code, err = _stream(str(src), "-o", str(out), "--pipe", kind, "--fps", "0", stdout=fh)
        assert code == 1
        _one_error(
            err,
            f"{src}: the frame size changed to 160x120 at frame 30",
            f"{kind.replace('mpegts', 'MPEG-TS')} stream started at 128x96",
        )
        records = _log(out)
        assert [r["index"] for r in records] == _frames(out) == list(range(30))
        with av.open(str(piped)) as c:  # the pipe's frames: the same 30, readable to the end
            assert sum(1 for _ in c.decode(video=0)) == 30


def test_a_disk_that_fills_mid_stream_ends_in_one_line_with_whole_outputs(
    tmp_path: Path, clips: dict[str, Path]
) -> None:
    # it was an OSError traceback; frames after a lost one were still published (a gap), and a log line cut by
    # the full disk stayed half-written
    with mounted_tmpfs(tmp_path / "disk1", "size=1m") as disk:
        out = disk / "out"
        code, err = _stream(str(clips["busy"]), "-o", str(out), "--format", "png", "--fps", "0")
        assert code == 1
        _one_error(err, f"{out / 'frames'}: cannot write (No space left on device)")
        frames = _frames(out)
        assert frames == list(range(len(frames))) and 0 < len(frames) < 40  # whole frames, no gap
        _log(out)  # whole records
    with mounted_tmpfs(tmp_path / "disk2", "size=8k") as disk:  # the log alone fills it
        out = disk / "out"
        code, err = _stream(str(clips["live"]), "-o", str(out), "--no-frames", "--fps", "0")
        assert code == 1
        _one_error(err, f"{out / 'gammas.jsonl'}: cannot write (No space left on device)")
        assert (out / "gammas.jsonl").read_bytes().endswith(b"}\n")
        records = _log(out)
        assert [r["index"] for r in records] == list(range(len(records))) and 0 < len(records) < 150

    with mounted_tmpfs(tmp_path / "disk3", "size=1m,ro") as disk:  # a read-only file system: OUT cannot be made
        out = disk / "out"
        code, err = _stream(str(clips["small"]), "-o", str(out))
        assert code == 1
        _one_error(err, f"{out}: cannot write (Read-only file system)")


def test_sigterm_mid_stream_leaves_every_output_whole(tmp_path: Path, clips: dict[str, Path]) -> None:
    out, piped = tmp_path / "out", tmp_path / "piped.ts"
    with open(piped, "wb") as fh:
        args = (str(clips["live"]), "--realtime", "-o", str(out), "--pipe", "mpegts", "--format", "png")
        proc = _stream_proc(*args, stdout=fh)
        try:
            _wait_for_records(out, 10, proc)
            proc.send_signal(signal.SIGTERM)
            _, raw = proc.communicate(timeout=60)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait(10)
    err = raw.decode(errors="replace")
    assert proc.returncode == 0 and "ended: stopped (SIGTERM)" in err and "Traceback" not in err, err
    records = _log(out)
    assert len(records) >= 10 and [r["index"] for r in records] == _frames(out)
    assert json.loads((out / "stream.json").read_text())["summary"]["frames_out"] == len(records)
    with av.open(str(piped)) as c:
        assert sum(1 for _ in c.decode(video=0)) == len(records)


def _y4m(clip: Path) -> bytes:
    exe = ffmpeg_exe()
    assert exe is not None
    cmd = [exe, "-v", "error", "-nostdin", "-i", str(clip), "-f", "yuv4mpegpipe", "-"]
    return subprocess.run(cmd, check=True, capture_output=True).stdout


@contextlib.contextmanager
def _fed_and_left_open(proc: subprocess.Popen[bytes], data: bytes) -> Iterator[None]:
    """``data`` written to ``proc``'s standard input, which stays open and silent for the block (not communicate(),
    which would close it: an end of the source); then the process is killed if it still runs."""
    assert proc.stdin is not None
    try:
        proc.stdin.write(data)
        proc.stdin.flush()
        yield
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
        proc.stdin.close()


@pytest.mark.parametrize("ending", ["ctrl-c", "duration"])
def test_a_source_gone_silent_does_not_hold_the_end_for_its_timeout(
    tmp_path: Path, clips: dict[str, Path], ending: str
) -> None:
    """Standard input that gave its frames and then says nothing (the writer alive, the pipe open): Ctrl-C, or the
    duration, ends the run at once, not a ``--timeout`` (60 s here) later, and the outputs are whole. The end used
    to wait for the reader, blocked in its read, for the timeout + 1 s."""
    out = tmp_path / "out"
    until = ("--duration", "6") if ending == "duration" else ()
    t0 = time.monotonic()
    proc = _stream_proc(
        "-",
        "-o",
        str(out),
        "--timeout",
        "60",
        "--drop",
        "never",
        *until,
        stdin=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
    )
    with _fed_and_left_open(proc, _y4m(clips["live"])):  # 150 frames at 30 fps: 90 at 18 fps
        _wait_for_records(out, 90, proc)
        if ending == "ctrl-c":
            t0 = time.monotonic()
            proc.send_signal(signal.SIGINT)
        proc.wait(45)
        took = time.monotonic() - t0
    assert proc.stderr is not None
    err = proc.stderr.read().decode(errors="replace")
    assert "Traceback" not in err, err
    # 6 s duration from the start of the run; a stop at once. Either way far below the 60 s timeout.
    assert took < (30 if ending == "duration" else 20), (took, err)
    end = "duration reached" if ending == "duration" else "stopped (Ctrl-C)"
    assert f"ended: {end}" in err, err
    records = _log(out)
    summary = json.loads((out / "stream.json").read_text())["summary"]
    assert summary["end"] == end and summary["frames_decoded"] == 150
    assert summary["frames_out"] == len(records) == 90 and [r["index"] for r in records] == _frames(out)


#: A library caller reading standard input: it stops the run once every frame it was given is read, the pipe still
#: open and silent, then asks whether the source was closed, and ends.
_LIBRARY_STDIN = """
import sys, threading, time
from colonlight.live import LiveStream, StreamOptions, parse_source
from colonlight.methods import create_method

live = LiveStream(parse_source("-"), create_method("none"), StreamOptions(timeout_s=60.0, drop="never"))

def stop_when_all_read():
    while live.summary.frames_decoded < int(sys.argv[1]):
        time.sleep(0.05)
    time.sleep(0.5)  # the reader is in its next read, which the pipe does not answer
    live.stop("stopped by the caller")

threading.Thread(target=stop_when_all_read, daemon=True).start()
summary = live.run()
t0 = time.perf_counter()
closed = live.wait_source_closed(5.0)
print(summary.end, summary.frames_decoded, closed, f"{time.perf_counter() - t0:.2f}", flush=True)
"""


def test_a_library_stop_on_a_silent_standard_input_ends_its_read_too(clips: dict[str, Path]) -> None:
    """From Python, a stop on standard input that gave its frames and stays open ends the reader's read as well as
    the run: the source is closed within a read's slice, and the script ends at once. FFmpeg's pipe read waited in
    the kernel: the reader stayed blocked while the pipe was silent, wait_source_closed said False, and the exit
    waited the timeout + 1 s (61 s here) for it."""
    proc = subprocess.Popen(
        [sys.executable, "-c", _LIBRARY_STDIN, "150"],
        env=colonlight_env(),
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    assert proc.stdout is not None and proc.stderr is not None
    with _fed_and_left_open(proc, _y4m(clips["live"])):  # 150 frames
        line = proc.stdout.readline().decode()
        t0 = time.monotonic()
        code = proc.wait(30)
        exit_s = time.monotonic() - t0
    err = proc.stderr.read().decode(errors="replace")
    assert code == 0 and "Traceback" not in err, err
    end, decoded, closed, close_s = line.rsplit(" ", 3)
    assert (end, decoded, closed) == ("stopped by the caller", "150", "True"), (line, err)
    assert float(close_s) < 2.0 and exit_s < 10.0, (line, exit_s)


def test_standard_input_that_pauses_longer_than_the_timeout_is_waited_for(
    tmp_path: Path, clips: dict[str, Path]
) -> None:
    """A pipe is not a network source: its producer may pause (a recorder that stalls) for longer than --timeout
    (1 s here), and every frame after the pause is still read; the stream ends when the pipe closes."""
    data = clips["live"].read_bytes()  # MPEG-TS: cut at a packet boundary, the halves join byte for byte
    half = len(data) // 188 // 2 * 188
    out = tmp_path / "out"
    proc = _stream_proc(
        "-", "-o", str(out), "--timeout", "1", "--fps", "0", "--drop", "never",
        stdin=subprocess.PIPE, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    assert proc.stdin is not None and proc.stderr is not None
    try:
        proc.stdin.write(data[:half])
        proc.stdin.flush()
        time.sleep(3.0)  # three timeouts of silence, the pipe open
        proc.stdin.write(data[half:])
        proc.stdin.close()
        code = proc.wait(60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    err = proc.stderr.read().decode(errors="replace")
    assert code == 0 and "Traceback" not in err, err
    summary = json.loads((out / "stream.json").read_text())["summary"]
    assert (summary["end"], summary["frames_decoded"], summary["frames_out"]) == ("source ended", 150, 150), err
    assert [r["index"] for r in _log(out)] == list(range(150))
