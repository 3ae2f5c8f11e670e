"""Where ``colonlight serve`` listens, through the real command.

Defect found: with its port in use, the server loaded the model, started the app, then logged uvicorn's "[Errno 98]
error while attempting to bind on address ('127.0.0.1', P)" and aborted in a C++ destructor ("terminate called
without an active exception"); a host that does not resolve likewise. The address is now bound before anything
loads: one line naming it and the cause, exit 1.
"""

from __future__ import annotations

import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from ..commands import colonlight_env, run_colonlight

pytestmark = pytest.mark.timeout(120)


def _serve(tmp_path: Path, *args: str) -> tuple[int, str]:
    return run_colonlight("serve", *args, env={"COLONLIGHT_DATA_DIR": str(tmp_path / "data")}, timeout=90)


def test_a_port_in_use_is_one_line_before_the_model_loads(tmp_path: Path) -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        code, output = _serve(tmp_path, "--host", "127.0.0.1", "--port", str(port))
    assert code == 1, output
    assert output.strip() == f"error: cannot listen on 127.0.0.1:{port}: address already in use", output


def test_a_host_that_does_not_resolve_is_one_line(tmp_path: Path) -> None:
    code, output = _serve(tmp_path, "--host", "no-such-host.invalid", "--port", "8000")
    assert code == 1, output
    lines = output.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: cannot listen on no-such-host.invalid:8000: "), output


def test_port_0_says_the_port_it_was_given_and_serves_on_it(tmp_path: Path) -> None:
    env = {**colonlight_env(), "COLONLIGHT_DATA_DIR": str(tmp_path / "data"), "COLONLIGHT_METHOD": "none"}
    proc = subprocess.Popen(
        [sys.executable, "-m", "colonlight_cli.main", "serve", "--host", "127.0.0.1", "--port", "0"],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    assert proc.stdout is not None
    try:
        deadline, seen = time.monotonic() + 90, []
        while time.monotonic() < deadline and not (seen and "running on" in seen[-1]):
            seen.append(proc.stdout.readline())
            assert seen[-1] or proc.poll() is None, "".join(seen)
        found = re.search(r"running on http://127\.0\.0\.1:(\d+) ", seen[-1])
        assert found and int(found[1]) != 0, "".join(seen)
        assert httpx.get(f"http://127.0.0.1:{found[1]}/healthz", timeout=10).json() == {"status": "ok"}
        proc.send_signal(signal.SIGINT)
        rest, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    assert proc.returncode == 0 and "Traceback" not in rest, rest
