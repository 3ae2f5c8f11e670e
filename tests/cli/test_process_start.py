"""Commands started in a process they cannot use as it is: a standard stream closed (``2>&-``, ``>&-``, ``<&-``,
or a parent that closed it), a current folder that was deleted, or a memory limit too small for the libraries.

Defects found: ``enhance`` with standard error closed did all its work and then exited 1 (an AttributeError, out of
sight, on flushing a stream Python had set to None); ``stream -`` with standard input closed, and ``stream --pipe``
with standard output closed, ended in a traceback. Now a closed descriptor is opened on the null device before
anything else is opened (so no output file takes its number), the report is dropped, and the two stream cases are
usage errors naming the closed stream. In a deleted current folder every command that loaded torch died with
"Intel oneMKL FATAL ERROR: Cannot load libtorch_cpu.so" (exit 2); it is now one line.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ..commands import PLAIN_CONSOLE, colonlight_command, colonlight_env
from ..media import X264, ffmpeg_exe, ffmpeg_fps_indices, make_clip, needs_ffmpeg
from ..ports import free_port

pytestmark = needs_ffmpeg


def _run_closed(fd: int, args: list[str], cwd: Path, module: bool = False) -> tuple[int, str]:
    """``colonlight ARGS`` (the console script, or ``python -m colonlight_cli.main``) with descriptor ``fd`` closed;
    its exit code and whatever it wrote to the standard streams still open."""
    cmd = [sys.executable, "-m", "colonlight_cli.main", *args] if module else colonlight_command(*args)
    done = subprocess.run(
        cmd,
        cwd=cwd,
        env={**colonlight_env(), **PLAIN_CONSOLE},
        stdin=subprocess.DEVNULL,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT if fd != 2 else subprocess.DEVNULL,
        preexec_fn=lambda: os.close(fd),  # in the child only, after the redirections
        timeout=240,
        check=False,
    )
    output = done.stdout.decode(errors="replace")
    assert "Traceback" not in output, output
    return done.returncode, output


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("closed-streams") / "clips"
    folder.mkdir()
    make_clip(folder / "a.mp4", 20, 25)
    return folder


@pytest.mark.parametrize(("fd", "module"), [(2, False), (2, True), (1, False)], ids=["stderr", "stderr-m", "stdout"])
def test_enhance_with_a_standard_stream_closed_succeeds_with_whole_outputs(
    clips: Path, tmp_path: Path, fd: int, module: bool
) -> None:
    code, output = _run_closed(fd, ["enhance", str(clips), "-o", "out", "-m", "none"], tmp_path, module)
    assert code == 0, output
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert [c["status"] for c in manifest["clips"]] == ["done"], manifest
    gammas = json.loads((tmp_path / "out" / "a" / "gammas.json").read_text())
    frames = sorted((tmp_path / "out" / "a" / "frames").iterdir())
    assert len(frames) == len(gammas["frames"]) == len(ffmpeg_fps_indices(clips / "a.mp4"))  # as ffmpeg's fps=18


def test_stream_from_a_closed_standard_input_is_a_usage_error(tmp_path: Path) -> None:
    code, output = _run_closed(0, ["stream", "-", "-o", "out", "-m", "none"], tmp_path)
    assert code == 2 and "standard input is closed" in output, output
    assert not (tmp_path / "out").exists()


def test_a_pipe_to_a_closed_standard_output_is_a_usage_error(clips: Path, tmp_path: Path) -> None:
    code, output = _run_closed(1, ["stream", str(clips / "a.mp4"), "--pipe", "y4m", "-m", "none"], tmp_path)
    assert code == 2 and "standard output is closed" in output, output


@pytest.mark.parametrize("module", [False, True], ids=["script", "module"])
def test_a_deleted_current_folder_is_one_line(clips: Path, tmp_path: Path, module: bool) -> None:
    gone = tmp_path / "gone"
    gone.mkdir()
    cmd = [sys.executable, "-m", "colonlight_cli.main"] if module else colonlight_command()
    done = subprocess.run(
        [*cmd, "enhance", str(clips), "-o", str(tmp_path / "out"), "-m", "none"],
        env={**colonlight_env(), **PLAIN_CONSOLE},
        capture_output=True,
        text=True,
        preexec_fn=lambda: (os.chdir(gone), os.rmdir(gone)),  # in the child only: its folder goes before it starts
        timeout=120,
        check=False,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 1, output
    assert output == "error: the current folder no longer exists (deleted, or moved away): cd to one that does\n"
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("limit_mb", [300, 800])
def test_a_memory_limit_too_small_for_the_libraries_is_one_line_naming_it(
    clips: Path, tmp_path: Path, limit_mb: int
) -> None:
    """Under an address-space limit (``ulimit -v``) the libraries fail to map: at 300 MB the command's own imports
    (numpy's OpenBLAS, FFmpeg's libavcodec), at 800 MB torch's. Each was a traceback, and torch's was "unknown
    method 'rnn'", which sent the user to check a name that was right."""
    import resource

    limit = limit_mb * 2**20
    done = subprocess.run(
        colonlight_command("enhance", clips, "-o", tmp_path / "out"),
        env={**colonlight_env(), **PLAIN_CONSOLE},
        capture_output=True,
        text=True,
        preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_AS, (limit, limit)),
        timeout=120,
        check=False,
    )
    output = done.stdout + done.stderr
    assert done.returncode == 1, output
    lines = output.splitlines()
    assert len(lines) == 1 and "too little memory to load the libraries: a limit such as `ulimit -v`?" in lines[0]
    assert lines[0].startswith(("error: cannot load colonlight's libraries: ", "error: method 'rnn' cannot be loaded"))


def test_an_unknown_method_and_one_that_does_not_load_are_told_apart() -> None:
    from colonlight import METHOD_NAMES, method_problem

    assert method_problem("rnn") is None and "rnn" in METHOD_NAMES
    assert method_problem("nope") == f"unknown method 'nope'; available: {', '.join(METHOD_NAMES)}"


def test_a_clip_that_ran_short_of_memory_or_threads_is_not_an_internal_error() -> None:
    """Under ``ulimit -v`` of 1.6 GB a clip failed with "internal error: RuntimeError: can't start new thread",
    which reads like a bug; both shortages now say what ran short (a clip's line and a job's error)."""
    from colonlight.errors import resource_shortage

    assert resource_shortage(MemoryError()) == "out of memory (too little memory, or a limit such as `ulimit -v`)"
    thread = resource_shortage(RuntimeError("can't start new thread"))
    assert thread is not None and thread.startswith("cannot start a thread")
    assert resource_shortage(RuntimeError("a bug")) is None and resource_shortage(ValueError()) is None


def test_a_stop_on_a_silent_network_source_with_standard_output_closed_ends_cleanly(tmp_path: Path) -> None:
    """``stream udp://... -o DIR >&-``, stopped with Ctrl-C while its source is silent: the command ends at once
    without waiting for the read it leaves behind, flushing its streams first. It flushed a ``sys.stdout`` that was
    None: a traceback, exit 1, and the interpreter's exit then waited out the 30 s read timeout."""
    exe = ffmpeg_exe()
    assert exe is not None
    clip = make_clip(tmp_path / "clip.ts", 30, 30, (128, 96), codec_args=(*X264, "-g", "15"))
    port = free_port(socket.SOCK_DGRAM, range(18800, 18850))
    args = ("stream", f"udp://127.0.0.1:{port}", "-o", tmp_path / "out", "-m", "none", "--timeout", "30")
    proc = subprocess.Popen(
        colonlight_command(*args),
        env={**colonlight_env(), **PLAIN_CONSOLE},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: os.close(1),
    )
    assert proc.stderr is not None
    try:
        assert "waiting for frames" in proc.stderr.readline()
        udp = f"udp://127.0.0.1:{port}?pkt_size=1316"
        subprocess.run([exe, "-v", "error", "-nostdin", "-re", "-i", str(clip), "-c", "copy", "-f", "mpegts", udp])
        time.sleep(1.0)  # silent now, the read waiting out its timeout
        t0 = time.monotonic()
        proc.send_signal(signal.SIGINT)
        code = proc.wait(60)
        took = time.monotonic() - t0
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    err = proc.stderr.read()
    assert code == 0 and "Traceback" not in err and "ended: stopped (Ctrl-C)" in err, err
    assert took < 10, took
    assert json.loads((tmp_path / "out" / "stream.json").read_text())["summary"]["frames_decoded"] > 0
