"""Output problems are one line, not a traceback (issue 13), on real file systems and real processes.

The output path is a file or on a read-only file system: a usage error (exit 2). The disk fills mid-run (a 2 MB
tmpfs the test mounts; root only, skipped with the reason otherwise): the clip that hit it fails naming its path
and the cause, the manifest stays valid, no temporary is left, the next clips are done, exit 1. Two batches on
one output folder: the second exits 2 naming the first's pid and host; no manifest entry is lost.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from colonlight.atomic import TMP_MARK

from ...commands import colonlight_command
from ...filesystems import mounted_tmpfs
from ...media import make_clip, make_noise_clip

GAMMA = ("--method", "gamma", "-q")  # a real method that needs no model: these tests are about outputs


def colonlight(*args: object, timeout: float = 300, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(colonlight_command(*args), capture_output=True, text=True, timeout=timeout, **kw)  # type: ignore[call-overload]


def one_error_line(stderr: str) -> str:
    """The single ``error:`` line of ``stderr``; fails on a traceback or on more than one."""
    assert "Traceback" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, stderr
    return lines[0]


def temporaries(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if TMP_MARK in p.name]


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """a.mp4 and c.mp4 (small), b.mp4 (random pixels: 30 frames of ~230 KB PNGs, more than a 2 MB disk holds)."""
    root = tmp_path_factory.mktemp("clips")
    make_clip(root / "a.mp4", n_frames=20, fps=25)
    make_noise_clip(root / "b.mp4", n_frames=30, fps=25)
    make_clip(root / "c.mp4", n_frames=20, fps=25)
    return root


def test_output_path_is_a_file(clips: Path, tmp_path: Path) -> None:
    target = tmp_path / "taken"
    target.write_text("not a folder")
    for out in (target, target / "below"):
        proc = colonlight("enhance", clips / "a.mp4", "-o", out, *GAMMA)
        assert proc.returncode == 2, proc.stderr
        line = one_error_line(proc.stderr)
        assert str(out) in line and ("is a file" in line), line
    assert target.read_text() == "not a folder"


def test_output_on_a_read_only_file_system(clips: Path, tmp_path: Path) -> None:
    with mounted_tmpfs(tmp_path / "ro", "size=1m,ro") as ro:  # a fresh, empty, read-only file system
        proc = colonlight("enhance", clips / "a.mp4", "-o", ro / "out", *GAMMA)
        assert proc.returncode == 2, proc.stderr
        assert "read-only file system" in one_error_line(proc.stderr)
    # a finished output folder, its file system remounted read-only
    with mounted_tmpfs(tmp_path / "rw", "size=1m") as rw:
        assert colonlight("enhance", clips / "a.mp4", "-o", rw / "out", *GAMMA).returncode == 0
        before = {p: p.read_bytes() for p in (rw / "out").rglob("*") if p.is_file()}
        subprocess.run(["mount", "-o", "remount,ro", str(rw)], check=True)
        proc = colonlight("enhance", clips / "a.mp4", "-o", rw / "out", *GAMMA)
        assert proc.returncode == 2, proc.stderr
        line = one_error_line(proc.stderr)
        assert str(rw / "out") in line and "read-only file system" in line, line
        assert {p: p.read_bytes() for p in (rw / "out").rglob("*") if p.is_file()} == before


@pytest.mark.parametrize("outputs", [("--frames", "--no-video"), ("--no-frames", "--video")], ids=["frames", "video"])
def test_disk_fills_mid_run(clips: Path, tmp_path: Path, outputs: tuple[str, str]) -> None:
    with mounted_tmpfs(tmp_path / "disk") as disk:
        if "--video" in outputs:  # an H.264 of noise is small: leave it less room
            (disk / "filler").write_bytes(b"\0" * 1_700_000)
        out = disk / "out"
        proc = colonlight("enhance", clips, "-o", out, "-j", "1", *outputs, *GAMMA)
        assert proc.returncode == 1, proc.stderr
        assert "Traceback" not in proc.stderr
        failed = [ln for ln in proc.stderr.splitlines() if ln.startswith("failed")]
        assert len(failed) == 1 and "b.mp4" in failed[0] and "No space left on device" in failed[0], proc.stderr
        manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))  # valid
        status = {c["clip"]: c["status"] for c in manifest["clips"]}
        assert status == {"a": "done", "b": "failed", "c": "done"}
        assert not temporaries(disk)
        assert not (out / "b").exists()  # what it wrote was removed, to free the room for the next clips
        for name in ("a", "c"):
            assert json.loads((out / name / "gammas.json").read_text())["frame_count"] == 14


def test_full_disk_keeps_the_last_complete_manifest(clips: Path, tmp_path: Path) -> None:
    """No room even for the manifest: every clip fails on one line, the earlier manifest is kept whole, exit 1."""
    with mounted_tmpfs(tmp_path / "disk") as disk:
        out = disk / "out"
        assert colonlight("enhance", clips / "a.mp4", "-o", out, *GAMMA).returncode == 0
        earlier = (out / "manifest.json").read_bytes()
        filler = disk / "filler"
        with open(filler, "wb") as fh:  # fill every block
            try:
                while True:
                    fh.write(b"\0" * 65536)
                    fh.flush()
            except OSError:
                pass
        proc = colonlight("enhance", clips / "c.mp4", "-o", out, *GAMMA)
        assert proc.returncode == 1, proc.stderr
        assert "Traceback" not in proc.stderr
        assert any("c.mp4" in ln and "No space left" in ln for ln in proc.stderr.splitlines()), proc.stderr
        assert "cannot write the manifest" in one_error_line(proc.stderr)
        assert (out / "manifest.json").read_bytes() == earlier
        assert not temporaries(disk)


def _holder_pid(lock: Path, proc: subprocess.Popen[str], timeout: float = 120) -> int:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            return int(json.loads(lock.read_text())["pid"])
        except (OSError, ValueError, KeyError):
            time.sleep(0.02)
    raise AssertionError(f"the first batch never took the lock: {proc.communicate()[1]}")


def test_two_batches_on_one_output_folder(tmp_path: Path) -> None:
    """Two real ``colonlight enhance`` processes: the second exits 2 naming the first; no entry is ever lost."""
    first, second = tmp_path / "first", tmp_path / "second"
    make_clip(first / "a1.mp4", n_frames=20, fps=25)
    make_clip(first / "a2.mp4", n_frames=1500, fps=30, size=(64, 48))  # 50 s of video: keeps the first busy
    make_clip(second / "b1.mp4", n_frames=20, fps=25)
    out = tmp_path / "out"
    a = subprocess.Popen(
        colonlight_command("enhance", str(first), "-o", str(out), "--fps", "0", *GAMMA),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        pid = _holder_pid(out / ".colonlight.lock", a)
        assert pid == a.pid
        b = colonlight("enhance", second, "-o", out, *GAMMA)
        still_running = a.poll() is None
        assert b.returncode == 2, b.stderr
        line = one_error_line(b.stderr)
        assert f"in use by colonlight pid {a.pid} on {socket.gethostname()}" in line, line
        assert still_running, "the first batch ended before the second tried: make it longer"
        a_out, a_err = a.communicate(timeout=600)
    finally:
        if a.poll() is None:
            a.kill()
            a.wait()
    assert a.returncode == 0, a_err
    assert "FileNotFoundError" not in a_err and "Traceback" not in a_err
    assert (out / ".colonlight.lock").read_bytes() == b""  # released, and emptied
    b = colonlight("enhance", second, "-o", out, *GAMMA)  # now it may
    assert b.returncode == 0, b.stderr
    manifest = json.loads((out / "manifest.json").read_text())
    assert {c["clip"]: c["status"] for c in manifest["clips"]} == {"a1": "done", "a2": "done", "b1": "done"}


def test_a_killed_batch_never_blocks_the_next(tmp_path: Path) -> None:
    """The kernel drops a dead holder's lock: the lock file left by a kill -9 does not block."""
    make_clip(tmp_path / "in" / "c.mp4", n_frames=20, fps=25)
    out = tmp_path / "out"
    holder = subprocess.Popen(
        [
            sys.executable,
            "-c",
            "import sys, time; from colonlight.outdir import output_lock\n"
            "with output_lock(sys.argv[1]):\n    print('locked', flush=True); time.sleep(600)",
            str(out),
        ],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "locked"
        proc = colonlight("enhance", tmp_path / "in", "-o", out, *GAMMA)
        assert proc.returncode == 2 and f"pid {holder.pid}" in one_error_line(proc.stderr)
    finally:
        holder.kill()
        holder.wait()
    assert json.loads((out / ".colonlight.lock").read_text())["pid"] == holder.pid  # stale record, no lock
    proc = colonlight("enhance", tmp_path / "in", "-o", out, *GAMMA)
    assert proc.returncode == 0, proc.stderr
