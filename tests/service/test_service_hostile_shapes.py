"""The hostile files of tests/cli/test_cli_hostile_shapes.py (1x1, 3x5 and one-row frames, a turned row, archives
renamed ``.mp4``, MP4 indexes that lie) uploaded to a real ``colonlight serve``: each is a succeeded job with an
even-sized ``enhanced.mp4`` or a one-line 415 naming the upload; no 5xx, no traceback in the log, no upload left."""

from __future__ import annotations

import io
import time
from collections.abc import Iterator
from pathlib import Path

import av
import httpx
import pytest

from ..cli.test_cli_hostile_shapes import DONE, FAILED, make_shapes
from ..media import needs_ffmpeg
from ..service_server import ServiceServer

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]


@pytest.fixture(scope="module")
def clips(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_shapes(tmp_path_factory.mktemp("hostile-shapes"))


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("hostile-shapes-server") / "data"
    with ServiceServer(data, {"COLONLIGHT_WORKERS": "1", "COLONLIGHT_METHOD": "none"}) as srv:
        yield srv


def test_each_is_a_job_or_a_one_line_415(clips: Path, server: ServiceServer) -> None:
    with httpx.Client(base_url=server.url, timeout=120) as client:
        for path in sorted(clips.iterdir()):
            name = path.stem
            r = client.post("/v1/jobs", files={"file": (path.name, path.read_bytes(), "video/mp4")})
            assert r.status_code < 500, (name, r.text)
            if name in FAILED:
                assert r.status_code == 415 and path.name in r.json()["message"], (name, r.text)
                assert "\n" not in r.json()["message"]
                continue
            assert r.status_code == 202, (name, r.text)
            deadline = time.monotonic() + 120
            while (job := client.get(r.headers["location"]).json())["status"] not in ("succeeded", "failed"):
                assert time.monotonic() < deadline, job
                time.sleep(0.1)
            assert job["status"] == "succeeded", job
            video = client.get(r.json()["links"]["video"])
            assert video.status_code == 200
            with av.open(io.BytesIO(video.content), mode="r") as c:
                s = c.streams.video[0]
                assert (s.codec_context.width, s.codec_context.height) == DONE[name], name
    assert list((server.data_dir / "uploads").iterdir()) == []
    assert "Traceback" not in server.log()
