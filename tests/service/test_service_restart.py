"""Jobs outlive the server: finished jobs are served after a restart, a job interrupted by a crash is resumed
(or, once out of attempts, marked failed with the reason), a clean shutdown re-queues the running job, and
finished jobs are swept after the TTL."""

from __future__ import annotations

import io
import time
from pathlib import Path

import av
import httpx
import pytest

from ..media import make_clip, needs_ffmpeg
from ..service_server import ServiceServer
from .test_service import assert_json_error, wait_done

pytestmark = [needs_ffmpeg, pytest.mark.timeout(180)]


def wait_running(c: httpx.Client, location: str, timeout: float = 60) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = c.get(location).json()
        if job["status"] == "running" and job["frames_done"] > 0:
            return job
        assert job["status"] in ("queued", "running"), job
        time.sleep(0.05)
    raise AssertionError(f"{location} never ran")


def test_restart_persistence_and_expiry(tmp_path: Path, random_weights: Path) -> None:
    short = make_clip(tmp_path / "short.mp4", n_frames=25, fps=25)
    long = make_clip(tmp_path / "long.mp4", n_frames=90, fps=25)  # fps=0: 90 frames, several seconds of work
    data = tmp_path / "data"
    env = {"COLONLIGHT_WEIGHTS": str(random_weights), "COLONLIGHT_WORKERS": "1"}

    def post(c: httpx.Client, path: Path, **fields: str) -> str:
        r = c.post("/v1/jobs", files={"file": (path.name, path.read_bytes())}, data={"fps": "0", **fields})
        assert r.status_code == 202, r.text
        return str(r.headers["location"])

    # 1. a finished job, and a job killed (SIGKILL) while running
    srv = ServiceServer(data, env).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            done = post(c, short)
            assert wait_done(c, done)["status"] == "succeeded"
            crashed = post(c, long)
            wait_running(c, crashed)
    finally:
        srv.kill()

    # 2. after the restart: the finished job is served, the crashed one resumes and completes
    srv = ServiceServer(data, env).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            job = c.get(done).json()
            assert job["status"] == "succeeded" and job["frames_done"] == 25
            with av.open(io.BytesIO(c.get(done + "/video").content)) as v:
                assert sum(1 for _ in v.decode(video=0)) == 25
            resumed = c.get(crashed).json()
            assert resumed["status"] in ("queued", "running") and resumed["note"] == "resumed after a server restart"
            final = wait_done(c, crashed, timeout=90)
            assert final["status"] == "succeeded" and final["frames_done"] == 90 and final["attempts"] == 2
            # a clean stop (SIGTERM) puts the running job back in the queue without spending an attempt
            stopped = post(c, long)
            wait_running(c, stopped)
    finally:
        assert srv.stop() in (0, -15)  # uvicorn re-raises SIGTERM after its graceful shutdown
        assert "Traceback" not in srv.log()

    # 3. with max_attempts=1: the re-queued job runs again; a crash then marks it failed, with the reason
    env3 = {**env, "COLONLIGHT_MAX_ATTEMPTS": "1"}
    srv = ServiceServer(data, env3).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            job = c.get(stopped).json()
            assert job["status"] in ("queued", "running") and job["note"] == "resumed after a server restart"
            job = wait_running(c, stopped)
            assert job["attempts"] == 1
    finally:
        srv.kill()
    env4 = {**env3, "COLONLIGHT_RESULT_TTL_SECONDS": "4", "COLONLIGHT_SWEEP_INTERVAL_SECONDS": "0.5"}
    srv = ServiceServer(data, env4).start()
    try:
        with httpx.Client(base_url=srv.url, timeout=60) as c:
            failed = c.get(stopped).json()
            assert failed["status"] == "failed" and "interrupted by a server stop" in failed["error"]
            assert_json_error(c.get(stopped + "/video"), 409)
            # 4. the TTL in force sweeps finished jobs, rows and files
            assert c.get(done).status_code == 404 or c.get(done).json()["expires_at"]
            deadline = time.monotonic() + 15
            while c.get(stopped).status_code != 404:
                assert time.monotonic() < deadline, "the failed job was never swept"
                time.sleep(0.25)
            assert_json_error(c.get(done), 404)
            # a job's row goes first, then its folder (a crash between them leaves an orphan the next start removes)
            while any((data / "jobs").iterdir()):
                assert time.monotonic() < deadline, f"left behind: {list((data / 'jobs').iterdir())}"
                time.sleep(0.1)
    finally:
        srv.stop()
