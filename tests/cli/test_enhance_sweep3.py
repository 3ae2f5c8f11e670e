"""A third hostile-input sweep of ``colonlight enhance``, through real processes on real files: Dask "schedulers"
that are not one (a port that accepts and never answers, a server that answers something else), a real loopback
cluster whose every worker dies mid-batch and whose scheduler dies mid-batch, and frames too wide for H.264's
``enhanced.mp4``. Each ends with one line per clip (or one line for the batch) and no traceback, never a hang;
the manifest stays valid and a rerun resumes to the bytes of an uninterrupted run."""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import pytest

from ..commands import run_colonlight
from ..media import make_clip, make_image_folder, needs_ffmpeg
from ..outputs import output_bytes

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

NONE = ("--method", "none", "-q", "-j", "1")


def _failed(output: str) -> dict[str, str]:
    """``failed`` lines by the file they name."""
    return {line.split()[1].rstrip(":"): line for line in output.splitlines() if line.startswith("failed")}


@contextlib.contextmanager
def _fake_scheduler(reply: bytes | None) -> Iterator[str]:
    """A loopback port that accepts connections and then sends ``reply`` (None: nothing), holding them open."""
    server = socket.create_server(("127.0.0.1", 0))
    held: list[socket.socket] = []

    def serve() -> None:
        with contextlib.suppress(OSError):
            while True:
                conn, _ = server.accept()
                held.append(conn)
                if reply is not None:
                    conn.sendall(reply)

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield f"tcp://127.0.0.1:{server.getsockname()[1]}"
    finally:
        server.close()
        for conn in held:
            conn.close()


@pytest.mark.parametrize(
    ("reply", "says"),
    [(None, "accepted the connection but sent no Dask handshake"), (b"HTTP/1.1 400 Bad Request\r\n\r\n", "")],
    ids=["silent", "http"],
)
def test_a_scheduler_address_that_does_not_answer_as_dask_is_one_line(
    tmp_path: Path, reply: bytes | None, says: str
) -> None:
    """Dask's Client bounds the connection by its timeout, not the handshake after it: a port that accepted and
    stayed silent held the batch forever, and an HTTP server's answer, read as a frame length of exabytes, ended
    in a MemoryError traceback (after which the half-made client's ``__del__`` hung 6 s more)."""
    pytest.importorskip("distributed")
    make_image_folder(tmp_path / "seq", n=3)
    with _fake_scheduler(reply) as address:
        t0 = time.monotonic()
        code, output = run_colonlight(
            "enhance", str(tmp_path / "seq"), "-o", str(tmp_path / "out"), "--cluster", address, *NONE,
            env={"COLONLIGHT_CLUSTER_TIMEOUT": "1"},
        )  # fmt: skip
        assert time.monotonic() - t0 < 20, output
    assert code == 1, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1 and f"cannot reach the Dask scheduler at {address}" in lines[0] and says in lines[0], output
    assert not (tmp_path / "out" / "manifest.json").exists()


@pytest.mark.parametrize("value", ["inf", "nan", "abc"])
def test_a_cluster_timeout_that_is_no_number_of_seconds_is_one_line(tmp_path: Path, value: str) -> None:
    """``inf`` (or ``1e300``) overflowed Dask's deadlines, so that every scheduler, even a live one, was
    "unreachable (timestamp out of range for platform time_t)"; ``nan`` and negative values became 0.5 s silently.
    A usage error (exit status 2), as a bad COLONLIGHT_FPS or COLONLIGHT_MAX_GAP_FRAMES is (it was 1)."""
    pytest.importorskip("distributed")
    make_image_folder(tmp_path / "seq", n=3)
    code, output = run_colonlight(
        "enhance", str(tmp_path / "seq"), "-o", str(tmp_path / "out"), "--cluster", "tcp://127.0.0.1:1", *NONE,
        env={"COLONLIGHT_CLUSTER_TIMEOUT": value},
    )  # fmt: skip
    assert code == 2, output
    assert (
        output.strip()
        == f"error: COLONLIGHT_CLUSTER_TIMEOUT must be a number of seconds from 0 to 86400, got {value!r}"
    )


def test_frames_too_wide_for_the_video_fail_that_clip_alone(tmp_path: Path) -> None:
    """2x16386 frames pass the pixel cap (0.03 Mpx), but x264 takes at most 16384 pixels a side: with ``--video``
    the clip failed as "internal error: ExternalError ... avcodec_open2(libx264)"; now one line says why, before
    anything is written, and the same frames are done without the video."""
    wide = tmp_path / "in" / "wide"
    wide.mkdir(parents=True)
    row = np.random.default_rng(1).integers(0, 255, (2, 16386, 3), dtype=np.uint8)
    for i in range(3):
        assert cv2.imwrite(str(wide / f"f{i}.png"), row)
    make_clip(tmp_path / "in" / "ok.mp4", 12)
    out = tmp_path / "out"
    code, output = run_colonlight("enhance", str(tmp_path / "in"), "-o", str(out), "--video", *NONE)
    assert code == 1, output
    assert _failed(output)[str(wide)].endswith(
        "frames of 16386x2 are too large for enhanced.mp4: H.264 takes at most 16384 pixels a side "
        "(without the video, --no-video, its frames can be written)"
    ), output
    entries = {e["clip"]: e["status"] for e in json.loads((out / "manifest.json").read_text())["clips"]}
    assert entries == {"wide": "failed", "ok": "done"}
    assert not (out / "wide").exists() and (out / "ok" / "enhanced.mp4").is_file()
    code, output = run_colonlight("enhance", str(wide), "-o", str(tmp_path / "frames-only"), *NONE)
    assert code == 0, output


# ------------------------------------------------------------------------------------------------ a real cluster


def test_a_cluster_that_loses_its_workers_then_its_scheduler_mid_batch(tmp_path: Path) -> None:
    """A loopback scheduler with one worker (no nanny: a dead worker stays dead).

    1. The worker is killed mid-clip: Dask keeps a task that no worker can run forever, so the batch waited
       forever. Now, once no worker has been connected for ``COLONLIGHT_CLUSTER_TIMEOUT``, every clip not
       finished fails in one line and the batch ends (exit 1, a valid manifest).
    2. A new worker, the same command; the scheduler is killed mid-clip: the clips fail as cancelled, and Dask's
       client logged an ERROR with a traceback on the console besides. Now only the one-line failures show.
    3. The same command without the cluster resumes to the bytes of an uninterrupted run.
    """
    pytest.importorskip("distributed")
    from ..engine.batch.test_cluster import LoopbackCluster, _executing

    videos = tmp_path / "videos"
    make_clip(videos / "long.mp4", n_frames=500, fps=25, size=(320, 240))
    make_clip(videos / "short.mp4", n_frames=40, fps=25, size=(160, 120))
    reference = tmp_path / "reference"
    code, output = run_colonlight("enhance", str(videos), "-o", str(reference), *NONE)
    assert code == 0, output
    out = tmp_path / "out"
    args = ("enhance", str(videos), "-o", str(out), *NONE)
    env = {**os.environ, "COLONLIGHT_CLUSTER_TIMEOUT": "2", "COLUMNS": "400"}

    def start_batch(address: str, log: Path) -> subprocess.Popen[bytes]:
        cmd = [sys.executable, "-m", "colonlight_cli.main", *args, "--cluster", address]
        with open(log, "wb") as sink:  # a file, not a pipe: nothing the batch writes can block it while we wait
            return subprocess.Popen(cmd, stdout=sink, stderr=subprocess.STDOUT, env=env)

    def finish(proc: subprocess.Popen[bytes], log: Path) -> tuple[int, str]:
        code = proc.wait(timeout=60)
        output = log.read_text(errors="replace")
        assert "Traceback" not in output, output
        return code, output

    cluster = LoopbackCluster(tmp_path / "dask")
    try:
        worker = cluster.ensure_workers(1)
        proc = start_batch(cluster.address, tmp_path / "workers-lost.log")
        try:
            deadline = time.monotonic() + 60
            while len(list((out / "long" / "frames").glob("*.png"))) < 3:  # mid-clip: some frames written
                assert time.monotonic() < deadline and proc.poll() is None, "never caught the clip running"
                time.sleep(0.02)
            cluster.kill(next(iter(worker)))
            t0 = time.monotonic()
            code, output = finish(proc, tmp_path / "workers-lost.log")
        finally:
            if proc.poll() is None:
                proc.kill()
        assert time.monotonic() - t0 < 20, output
        assert code == 1, output
        assert f"{videos / 'long.mp4'}" in _failed(output), output
        assert all("no Dask worker has been connected to the scheduler" in line for line in _failed(output).values())
        manifest = json.loads((out / "manifest.json").read_text())
        assert {e["clip"] for e in manifest["clips"]} == {"long", "short"}
        assert not (out / "long" / "gammas.json").exists()

        address = next(iter(cluster.ensure_workers(1).values()))
        proc = start_batch(cluster.address, tmp_path / "scheduler-lost.log")
        try:
            deadline = time.monotonic() + 60
            while not _executing(cluster, address):
                assert time.monotonic() < deadline and proc.poll() is None, "never caught a clip running"
                time.sleep(0.02)
            cluster.client.close(timeout=5)
            del cluster.client  # the harness's client would log its own reconnect attempts
            cluster.scheduler.send_signal(signal.SIGKILL)
            code, output = finish(proc, tmp_path / "scheduler-lost.log")
        finally:
            if proc.poll() is None:
                proc.kill()
        assert code == 1, output
        assert "lost the Dask scheduler" in output, output
        json.loads((out / "manifest.json").read_text())
    finally:
        cluster.close()  # its worker, which ran on without the scheduler, too

    code, output = run_colonlight(*args)
    assert code == 0, output
    assert output_bytes(out) == output_bytes(reference)
