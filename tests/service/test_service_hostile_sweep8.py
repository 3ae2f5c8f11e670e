"""Sweep 8's files (tests/cli/test_hostile_sweep8.py) uploaded to a real ``colonlight serve``: a recording with a
smaller preview stream of a higher bit rate is enhanced from the recording, as ``ffmpeg -i`` maps it (the job
enhanced the preview); a short note FFmpeg probes as CD+G karaoke graphics is a 415 (it was a job that failed);
an MP4 cut inside its index is a 415 that says it is truncated (it said "contains no video stream")."""

from __future__ import annotations

import io
import time
from collections.abc import Iterator
from pathlib import Path

import av
import httpx
import pytest

from ..cli.test_hostile_sweep8 import cut_in_index, make_two_stream_clip
from ..media import ffmpeg_fps_indices, make_clip, needs_ffmpeg, read_index
from ..service_server import ServiceServer

pytestmark = [needs_ffmpeg, pytest.mark.timeout(180)]


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("sweep8-server") / "data"
    with ServiceServer(data, {"COLONLIGHT_WORKERS": "1", "COLONLIGHT_METHOD": "none"}) as srv:
        yield srv


def upload(client: httpx.Client, name: str, body: bytes) -> httpx.Response:
    return client.post("/v1/jobs", files={"file": (name, body, "application/octet-stream")})


def test_a_two_stream_upload_is_enhanced_from_its_larger_picture(
    tmp_path: Path, server: ServiceServer, client: httpx.Client
) -> None:
    clip, big = make_two_stream_clip(tmp_path, "mp4")
    r = upload(client, clip.name, clip.read_bytes())
    assert r.status_code == 202, r.text
    deadline = time.monotonic() + 60
    while (job := client.get(r.headers["location"]).json())["status"] not in ("succeeded", "failed"):
        assert time.monotonic() < deadline, job
        time.sleep(0.1)
    assert job["status"] == "succeeded", job
    video = client.get(r.json()["links"]["video"])
    with av.open(io.BytesIO(video.content), mode="r") as c:
        frames = [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]
    assert {f.shape for f in frames} == {(96, 128, 3)}
    assert [read_index(f) for f in frames] == ffmpeg_fps_indices(big, 18)
    assert "Traceback" not in server.log()


def test_a_note_and_an_mp4_cut_in_its_index_are_one_line_415s(
    tmp_path: Path, server: ServiceServer, client: httpx.Client
) -> None:
    r = upload(client, "NOTES", b"In this folder: two clips of 2024.\n")
    assert r.status_code == 415, r.text
    assert r.json()["message"].startswith("NOTES: not a video"), r.text
    src = make_clip(tmp_path / "src.mp4", 60, 25, size=(32, 32))
    at = cut_in_index(src, tmp_path / "cut.mp4", 0.1)
    r = upload(client, "cut.mp4", (tmp_path / "cut.mp4").read_bytes())
    assert r.status_code == 415, r.text
    message = r.json()["message"]
    assert message.startswith(f"cut.mp4: truncated MP4/MOV: the file ends at byte {at}, inside its index"), message
    assert "\n" not in message and str(tmp_path) not in message
    assert list((server.data_dir / "uploads").iterdir()) == []
