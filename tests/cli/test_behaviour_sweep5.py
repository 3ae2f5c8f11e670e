"""Behaviour sweep 5 (CLI): what `colonlight stream` reports about a live source that ends.

A UDP MPEG-TS stream that simply stops (the sender's end, no reconnect) ended with the warning "decoding fell up
to 2.0 s behind the source's clock (the machine could not keep up ...)", on an idle machine too: the demuxer and
the decoder release their last frames only once ``--timeout`` s of silence have passed, and those frames counted
as a backlog of ``--timeout`` seconds. They are the source's tail, not a lag.
"""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
from pathlib import Path

from ..commands import colonlight_env
from ..media import ffmpeg_exe, needs_ffmpeg
from ..ports import free_port

pytestmark = needs_ffmpeg

PORTS = range(18600, 18700)  # this file's loopback ports


def test_udp_stream_that_ends_is_not_reported_as_falling_behind(tmp_path: Path) -> None:
    port = free_port(socket.SOCK_DGRAM, PORTS)
    out = tmp_path / "live"
    cmd = [sys.executable, "-m", "colonlight_cli.main", "stream", f"udp://127.0.0.1:{port}", "-o", str(out)]
    proc = subprocess.Popen(
        [*cmd, "--method", "none", "--timeout", "2"],
        env=colonlight_env(),
        stderr=subprocess.PIPE,
        stdout=subprocess.DEVNULL,
    )
    try:
        time.sleep(2.0)  # the listener binds the port before the sender starts
        exe = ffmpeg_exe()
        assert exe is not None
        sender = subprocess.run(
            [exe, "-hide_banner", "-loglevel", "error", "-nostdin", "-re", "-f", "lavfi"]
            + ["-i", "testsrc2=size=96x80:rate=18", "-t", "3", "-c:v", "libx264", "-preset", "ultrafast"]
            + ["-f", "mpegts", f"udp://127.0.0.1:{port}?pkt_size=1316"],
            capture_output=True,
            timeout=60,
        )
        assert sender.returncode == 0, sender.stderr.decode(errors="replace")
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    text = err.decode(errors="replace")
    assert proc.returncode == 0, text
    assert "source lost" in text and "frames in" in text
    summary = json.loads((out / "stream.json").read_text())["summary"]
    assert summary["frames_out"] >= 10
    assert summary["behind_max_s"] < 1.0, text  # was the --timeout (2 s): the tail released at the end
    assert "behind the source's clock" not in text, text
