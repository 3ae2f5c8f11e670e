"""A full data folder is a JSON 507 (or a job failed with the reason), never a 500, and leaves nothing behind:
the server runs on a small tmpfs mounted as its data folder (needs root; skipped with the reason otherwise)."""

from __future__ import annotations

import os
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from ..filesystems import mounted_tmpfs
from ..media import make_clip, needs_ffmpeg
from ..service_server import ServiceServer
from .test_service import assert_json_error, leftovers, wait_done

pytestmark = [needs_ffmpeg, pytest.mark.timeout(240)]

TMPFS_MB = 16


@pytest.fixture(scope="module")
def small_disk(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    with mounted_tmpfs(tmp_path_factory.mktemp("small-disk"), f"size={TMPFS_MB}m") as mount_point:
        yield mount_point


@pytest.fixture(scope="module")
def server(small_disk: Path, random_weights: Path) -> Iterator[ServiceServer]:
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_MAX_UPLOAD_MB": str(4 * TMPFS_MB),
        "COLONLIGHT_SYNC_MAX_SECONDS": "5",
    }
    with ServiceServer(small_disk / "data", env, log=small_disk.parent / "small-disk-server.log") as srv:
        yield srv
    assert "Traceback" not in srv.log()


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("disk-clips") / "p7.mp4", n_frames=25, fps=25, size=(256, 192))


def free_bytes(path: Path) -> int:
    st = os.statvfs(path)
    return st.f_bavail * st.f_frsize


def fill(disk: Path, leave: int) -> Path:
    """A filler file that leaves about ``leave`` bytes free on ``disk``."""
    filler = disk / "filler"
    with open(filler, "ab") as fh:
        fh.truncate(0)
        todo = free_bytes(disk) - leave
        block = b"\xff" * (1 << 20)
        while todo > 0:
            fh.write(block[: min(len(block), todo)])
            todo -= len(block)
    return filler


def post(client: httpx.Client, route: str, path: Path, **fields: str) -> httpx.Response:
    return client.post(route, files={"file": (path.name, path.read_bytes(), "video/mp4")}, data=fields)


def test_upload_that_fills_the_disk_is_507(
    client: httpx.Client, server: ServiceServer, small_disk: Path, tmp_path: Path
) -> None:
    big = tmp_path / "big.mp4"
    big.write_bytes(os.urandom((TMPFS_MB + 4) << 20))  # more than the whole disk, less than the upload limit
    free_before = free_bytes(small_disk)
    for route in ("/v1/jobs", "/v1/enhance"):
        r = client.post(route, files={"file": (big.name, big.read_bytes(), "video/mp4")})
        body = assert_json_error(r, 507)
        assert body["code"] == "insufficient_storage" and "full" in body["message"]
        assert leftovers(server) == []  # the partial upload was removed ...
        assert free_bytes(small_disk) >= free_before - (64 << 10)  # ... and its space is free again


def test_results_that_do_not_fit_fail_the_job_with_the_reason(
    client: httpx.Client, server: ServiceServer, small_disk: Path, clip: Path
) -> None:
    filler = fill(small_disk, leave=clip.stat().st_size + (24 << 10))  # room for the upload, not its results
    try:
        r = post(client, "/v1/jobs", clip)
        if r.status_code == 507:  # the job table itself had no room: also a clean refusal
            assert_json_error(r, 507)
        else:
            assert r.status_code == 202, r.text
            job = wait_done(client, r.headers["location"], timeout=120)
            assert job["status"] == "failed" and "no space left" in job["error"], job
            assert not list((server.data_dir / "jobs" / job["id"]).glob("input*"))  # its upload is gone
            assert_json_error(client.get(job["links"]["video"]), 409)
        sync = post(client, "/v1/enhance", clip)
        assert_json_error(sync, 507)
        assert leftovers(server) == [] and list((server.data_dir / "sync").iterdir()) == []
    finally:
        filler.unlink()
    ok = post(client, "/v1/jobs", clip)  # with room again, the server carries on
    assert ok.status_code == 202, ok.text
    assert wait_done(client, ok.headers["location"], timeout=120)["status"] == "succeeded"


def test_frames_zip_on_a_full_disk_is_507(
    client: httpx.Client, server: ServiceServer, small_disk: Path, clip: Path
) -> None:
    r = post(client, "/v1/jobs", clip)
    assert r.status_code == 202, r.text
    job = wait_done(client, r.headers["location"], timeout=120)
    assert job["status"] == "succeeded", job
    filler = fill(small_disk, leave=0)
    try:
        assert_json_error(client.get(job["links"]["frames"]), 507)
        job_dir = server.data_dir / "jobs" / job["id"]
        assert sorted(p.name for p in job_dir.iterdir()) == ["out"]  # no half-written zip
        assert client.get(job["links"]["gammas"]).status_code == 200  # what exists is still served
    finally:
        filler.unlink()
    zipped = client.get(job["links"]["frames"])
    assert zipped.status_code == 200 and zipped.headers["content-type"] == "application/zip"
