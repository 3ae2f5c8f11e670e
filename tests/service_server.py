"""A real ``colonlight serve`` (uvicorn) in a subprocess on a free loopback port, for the service tests.

Started exactly as the README says (``colonlight serve --host 127.0.0.1 --port P`` with ``COLONLIGHT_*``
variables), so the tests exercise the command, the settings, the app and uvicorn together.
"""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from collections.abc import Mapping
from pathlib import Path

import httpx

from .commands import colonlight_env
from .ports import free_port


class ServiceServer:
    """``with ServiceServer(data_dir, env) as srv: httpx.get(srv.url + "/healthz")``."""

    def __init__(self, data_dir: Path, env: Mapping[str, str] | None = None, log: Path | None = None) -> None:
        self.data_dir = Path(data_dir)
        self.extra_env = dict(env or {})
        self.log_path = log or self.data_dir.parent / f"{self.data_dir.name}-server.log"
        self.port = 0
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    def start(self, wait_ready: bool = True, timeout: float = 180.0) -> ServiceServer:
        self.port = free_port()
        env = colonlight_env()
        env.update({"COLONLIGHT_DATA_DIR": str(self.data_dir), "COLONLIGHT_LOG_LEVEL": "warning", **self.extra_env})
        log = open(self.log_path, "ab")  # noqa: SIM115 - kept open for the process's life
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "colonlight_cli.main", "serve", "--host", "127.0.0.1", "--port", str(self.port)],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        log.close()
        deadline = time.monotonic() + timeout
        path = "/readyz" if wait_ready else "/healthz"
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"server exited with {self.proc.returncode}:\n{self.log()}")
            try:
                if httpx.get(self.url + path, timeout=2).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.stop()
        raise RuntimeError(f"server not ready within {timeout} s:\n{self.log()}")

    def log(self) -> str:
        try:
            return self.log_path.read_text(errors="replace")[-5000:]
        except OSError:
            return ""

    def stop(self, timeout: float = 20.0) -> int | None:
        """SIGTERM (uvicorn's graceful shutdown), SIGKILL if it lingers; returns the exit code."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)
        code = self.proc.returncode
        self.proc = None
        return code

    def kill(self) -> None:
        """SIGKILL: a crash, with no chance to clean up."""
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait(10)
            self.proc = None

    def peak_rss_bytes(self) -> int | None:
        """VmHWM of the server process (its peak resident memory)."""
        if self.proc is None:
            return None
        try:
            for line in Path(f"/proc/{self.proc.pid}/status").read_text().splitlines():
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) * 1024
        except OSError:
            return None
        return None

    def __enter__(self) -> ServiceServer:  # noqa: PYI034
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()
