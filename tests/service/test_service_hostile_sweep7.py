"""Hostile input against a real ``colonlight serve`` (uvicorn on loopback), seventh sweep: request options whose
values Python's number parsers refuse in their own words.

* A ``/v1/stream`` start message with a numeric option written as a JSON integer past a float's range
  (``"gamma": 1`` and 400 zeros) raised OverflowError inside the option check: the stream closed with
  ``internal_error`` (1011) and a traceback reached the server log. It is now a ``validation_error`` (1008).
* ``model_size=²`` (a superscript, which ``str.isdigit`` takes) was a 422 quoting ``int()``: "Value error, invalid
  literal for int() with base 10"; 5000 digits quoted Python's "Exceeds the limit (4300 digits) for integer string
  conversion ... use sys.set_int_max_str_digits()". Both now give the option's own message, and a value that long
  is shown shortened, not echoed whole.
* ``COLONLIGHT_DATA_DIR`` naming a file, a path under a file, a link loop or a name past NAME_MAX started uvicorn,
  then ended in a traceback (NotADirectoryError, RuntimeError "Symlink loop from ...", OSError "File name too
  long") and "Application startup failed". It is now one line and exit 2, as a bad COLONLIGHT_MAX_GAP_FRAMES is.
"""

from __future__ import annotations

import contextlib
import json
import os
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from websockets.sync.client import connect

from ..media import make_clip, needs_ffmpeg
from ..service_server import ServiceServer

pytestmark = pytest.mark.timeout(120)

SIZE_MESSAGE = "model_size must be an integer 8..1024, 'full' or 'auto', got "


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("sweep7") / "data"
    srv = ServiceServer(data, {"COLONLIGHT_METHOD": "gamma", "COLONLIGHT_WORKERS": "1"}).start()
    try:
        yield srv
        assert "Traceback" not in srv.log(), srv.log()
    finally:
        srv.stop()


def _start(server: ServiceServer, start: str) -> tuple[dict, int | None]:
    """Send ``start`` (raw JSON text) as a stream's first message: the answer and the close code."""
    url = server.url.replace("http://", "ws://") + "/v1/stream"
    with connect(url, proxy=None, max_size=None, compression=None) as ws:
        ws.send(start)
        answer = json.loads(ws.recv(timeout=30))
        with contextlib.suppress(Exception):  # the server closes the stream after the error
            ws.recv(timeout=30)
        return answer, ws.close_code


@pytest.mark.parametrize("field", ["gamma", "tone_match", "scene_cut"])
def test_a_stream_option_past_a_floats_range_is_a_validation_error(server: ServiceServer, field: str) -> None:
    method = "gamma" if field == "gamma" else "rnn"
    answer, code = _start(server, f'{{"type": "start", "method": "{method}", "{field}": 1{"0" * 400}}}')
    assert answer["type"] == "error" and answer["code"] == "validation_error", answer
    assert f"{field} must be a number" in answer["message"] and "(401 characters)" in answer["message"], answer
    assert len(answer["message"]) < 300, answer
    assert code == 1008
    assert "Traceback" not in server.log(), server.log()


@pytest.mark.parametrize("size", ["²", "1" * 5000], ids=["superscript", "5000-digits"])
def test_a_model_size_int_refuses_is_the_options_own_422(tmp_path: Path, server: ServiceServer, size: str) -> None:
    answer, code = _start(server, json.dumps({"type": "start", "method": "rnn", "model_size": size}))
    assert answer["code"] == "validation_error" and SIZE_MESSAGE in answer["message"], answer
    assert "int()" not in answer["message"] and "4300" not in answer["message"], answer
    assert code == 1008


@needs_ffmpeg
def test_a_model_size_int_refuses_in_a_form_is_the_options_own_422(tmp_path: Path, server: ServiceServer) -> None:
    clip = make_clip(tmp_path / "a.mp4", 4, size=(64, 48)).read_bytes()
    before = sorted((server.data_dir / "jobs").iterdir())
    for size in ("²", "1" * 5000):
        r = httpx.post(
            server.url + "/v1/jobs",
            files={"file": ("a.mp4", clip, "video/mp4")},
            data={"method": "rnn", "model_size": size},
            timeout=60,
        )
        assert r.status_code == 422, r.text
        message = r.json()["message"]
        assert SIZE_MESSAGE in message and "int()" not in message and "4300" not in message, message
        assert len(message) < 300, message
    assert sorted((server.data_dir / "jobs").iterdir()) == before


@pytest.mark.parametrize("place", ["file", "under-a-file", "loop", "too-long"])
def test_a_data_folder_that_cannot_be_one_stops_the_server_in_one_line(tmp_path: Path, place: str) -> None:
    (tmp_path / "file").write_bytes(b"x")
    os.symlink("loop", tmp_path / "loop")
    data = {
        "file": tmp_path / "file",
        "under-a-file": tmp_path / "file" / "data",
        "loop": tmp_path / "loop" / "data",
        "too-long": tmp_path / ("x" * 300),
    }[place]
    srv = ServiceServer(data, {"COLONLIGHT_METHOD": "gamma"}, log=tmp_path / "server.log")
    with pytest.raises(RuntimeError, match="server exited with 2"):
        srv.start(timeout=60)
    lines = [line for line in srv.log().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: COLONLIGHT_DATA_DIR: Value error, {data}: "), lines
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "loop", "server.log"]


def test_a_data_folder_whose_subfolder_cannot_be_made_stops_the_server_in_one_line(tmp_path: Path) -> None:
    """A file where the server's ``jobs/`` folder goes passes the settings' check (the data folder itself is one)
    and was uvicorn's "Application startup failed" traceback: ``serve`` now makes the folders before it starts."""
    data = tmp_path / "data"
    data.mkdir()
    (data / "jobs").write_bytes(b"the user's own")
    srv = ServiceServer(data, {"COLONLIGHT_METHOD": "gamma"}, log=tmp_path / "server.log")
    with pytest.raises(RuntimeError, match="server exited with 2"):
        srv.start(timeout=60)
    lines = [line for line in srv.log().splitlines() if line.strip()]
    assert lines == [
        f"error: COLONLIGHT_DATA_DIR: cannot create or write {data}/jobs: a file is in the way of a folder"
    ]
    assert (data / "jobs").read_bytes() == b"the user's own"


def test_a_negative_zero_rate_is_recorded_as_every_frame() -> None:
    """``fps=-0`` is a usable rate (every frame) and was recorded as ``-0.0`` in the job's options."""
    from colonlight_service.request_options import JobOptions

    options = JobOptions.model_validate({"fps": "-0"})
    assert options.fps == 0.0 and str(options.fps) == "0.0"
    assert JobOptions.model_validate({"fps": 18}).fps == 18
