"""Free loopback ports for the tests that run real servers and streams (uvicorn, ffmpeg senders, listeners)."""

from __future__ import annotations

import os
import socket


def free_port(kind: int = socket.SOCK_STREAM, ports: range | None = None) -> int:
    """A loopback port that a socket of ``kind`` (TCP or UDP) can bind now.

    Taken from ``ports`` when given (a suite's own range, so that suites running side by side do not collide),
    else from ``COLONLIGHT_TEST_PORTS`` (e.g. ``18300-18399``) when that is set, else any the system offers.
    """
    if ports is None:
        low, _, high = os.environ.get("COLONLIGHT_TEST_PORTS", "").partition("-")
        ports = range(int(low), int(high or low) + 1) if low.isdigit() else range(0, 1)
    for port in ports:
        with socket.socket(socket.AF_INET, kind) as s:
            try:
                s.bind(("127.0.0.1", port))
            except OSError:
                continue
            return int(s.getsockname()[1])
    raise RuntimeError(f"no free loopback port in {ports.start}-{ports.stop - 1}")
