"""``/v1/stream`` against a real ``colonlight serve`` (uvicorn) on loopback, with a real WebSocket client.

One server for the module: an API key, at most 2 streams, 1 MiB messages, short idle and send timeouts, so that
every limit can be reached quickly. The results are checked against the engine run here on the same frames.
"""

from __future__ import annotations

import base64
import hashlib
import json
import math
import os
import socket
import struct
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from colonlight import live_content_stream, load_content_mask
from colonlight.methods import create_method

from ..media import flat_png, make_clip
from ..service_server import ServiceServer

pytestmark = pytest.mark.timeout(120)

KEY = "s3cret-k3y"
SEND_TIMEOUT_S = 3.0
IDLE_S = 6.0
START_TIMEOUT_S = 180.0  # loading torch takes a while on a busy machine


@pytest.fixture(scope="module")
def weights(random_weights: Path) -> Path:
    return random_weights


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, weights: Path) -> Iterator[ServiceServer]:
    env = {
        "COLONLIGHT_WEIGHTS": str(weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_API_KEY": KEY,
        "COLONLIGHT_STREAM_MAX": "2",
        "COLONLIGHT_STREAM_MAX_FRAME_MB": "1",
        "COLONLIGHT_STREAM_IDLE_SECONDS": str(IDLE_S),
        "COLONLIGHT_STREAM_SEND_TIMEOUT_SECONDS": str(SEND_TIMEOUT_S),
    }
    srv = ServiceServer(tmp_path_factory.mktemp("stream") / "data", env).start(timeout=START_TIMEOUT_S)
    try:
        yield srv
        assert "Traceback" not in srv.log(), srv.log()
    finally:
        srv.stop()


def ws_url(srv: ServiceServer) -> str:
    return srv.url.replace("http://", "ws://") + "/v1/stream"


def open_stream(srv: ServiceServer, key: str | None = KEY, **headers: str) -> ClientConnection:
    hdrs = dict(headers)
    if key is not None:
        hdrs["X-API-Key"] = key
    return connect(
        ws_url(srv),
        additional_headers=hdrs,
        proxy=None,
        max_size=None,
        compression=None,
        open_timeout=20,
        close_timeout=5,
    )


def recv_json(ws: ClientConnection, timeout: float = 60) -> dict[str, Any]:
    message = ws.recv(timeout)
    assert isinstance(message, str), f"expected a JSON text message, got {len(message)} bytes"
    value: dict[str, Any] = json.loads(message)
    return value


def closed_with(ws: ClientConnection, timeout: float = 30) -> tuple[int, str, list[dict[str, Any]]]:
    """Read until the server closes; (close code, reason, the JSON messages before it)."""
    messages: list[dict[str, Any]] = []
    with pytest.raises(ConnectionClosed) as info:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            m = ws.recv(max(0.1, deadline - time.monotonic()))
            if isinstance(m, str):
                messages.append(json.loads(m))
    rcvd = info.value.rcvd
    assert rcvd is not None, "the connection dropped without a close frame"
    return rcvd.code, rcvd.reason, messages


def scene(n: int, w: int = 160, h: int = 120, seed: int = 0) -> list[np.ndarray]:
    """A dark tunnel whose light swings, with some texture: what the model reacts to."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    frames = []
    for i in range(n):
        r = np.hypot(x - w / 2 - 10 * math.sin(i / 3), y - h / 2) / (0.5 * math.hypot(w, h))
        lum = np.clip(r * 1.6, 0, 1) * (0.5 + 0.4 * math.sin(i / 2.5)) * (0.8 + 0.2 * np.sin(r * 30 - i))
        rgb = lum[..., None] * np.array([230, 130, 110], np.float32) + rng.normal(0, 3, (h, w, 1))
        frames.append(np.clip(rgb, 0, 255).astype(np.uint8))
    return frames


def png(rgb: np.ndarray) -> bytes:
    return bytes(cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))[1])


def jpeg(rgb: np.ndarray, quality: int = 90) -> bytes:
    return bytes(cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])[1])


def decode(data: bytes) -> np.ndarray:
    return cv2.cvtColor(cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def engine_run(weights: Path, frames: list[np.ndarray]) -> list[tuple[float | None, np.ndarray]]:
    stream = create_method("rnn", weights=str(weights), device="cpu").stream()
    return [(r.gamma, r.frame) for f in frames for r in stream.push(f)]


def metric(srv: ServiceServer, name: str) -> float:
    text = httpx.get(srv.url + "/metrics", headers={"X-API-Key": KEY}, timeout=10).text
    return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines() if line.startswith(name))


# ---------------------------------------------------------------------------------------------- the protocol


def test_results_come_in_order_with_one_state_per_connection(server: ServiceServer, weights: Path) -> None:
    """Two connections at once, frames interleaved: each answer is the engine's own result for its stream."""
    a_frames = scene(10, seed=1)
    b_frames = scene(10, seed=2)[::-1]
    with open_stream(server) as a, open_stream(server, key=None, Authorization=f"Bearer {KEY}") as b:
        a.send(json.dumps({"type": "start", "format": "png"}))
        b.send(json.dumps({"type": "start", "format": "png", "method": "rnn"}))
        ready = recv_json(a)
        assert recv_json(b)["type"] == "ready"
        assert ready["type"] == "ready" and ready["method"] == "rnn" and ready["format"] == "png"
        assert ready["parameters"]["seeds"] == 2 and ready["max_pixels"] > 0
        got: dict[str, list[tuple[dict[str, Any], np.ndarray]]] = {"a": [], "b": []}
        for i in range(10):
            for ws, frames in ((a, a_frames), (b, b_frames)):
                ws.send(json.dumps({"type": "frame", "time": i / 30}))
                ws.send(png(frames[i]))
            for name, ws in (("a", a), ("b", b)):
                record = recv_json(ws)
                image = ws.recv(60)
                assert isinstance(image, bytes) and len(image) == record["bytes"]
                got[name].append((record, decode(image)))
        a.send(json.dumps({"type": "end"}))
        code, reason, tail = closed_with(a)
        assert (code, tail[-1]) == (1000, {"type": "end", "frames": 10, "errors": 0})
    for name, frames in (("a", a_frames), ("b", b_frames)):
        expected = engine_run(weights, frames)
        records = [r for r, _ in got[name]]
        assert [r["index"] for r in records] == list(range(10))
        assert [r["time"] for r in records] == [i / 30 for i in range(10)]
        assert [r.get("seed", False) for r in records] == [True, True] + [False] * 8
        assert all((r["width"], r["height"]) == (160, 120) and r["latency_ms"] >= 0 for r in records)
        for (record, image), (gamma, frame) in zip(got[name], expected, strict=True):
            assert record["gamma"] == pytest.approx(gamma, abs=1e-5)
            assert np.abs(image.astype(int) - frame).max() <= 1  # PNG: lossless, up to a LUT rounding
        assert len({round(r["gamma"], 4) for r in records[2:]}) > 3  # the state moves: not one constant gamma
    assert got["a"][4][0]["gamma"] != pytest.approx(got["b"][4][0]["gamma"], abs=1e-4)


def test_jpeg_frames_without_a_start_message(server: ServiceServer) -> None:
    """The minimal client: binary frames only; the server's defaults apply and JPEG comes back."""
    with open_stream(server) as ws:
        ws.send(jpeg(scene(1, 320, 240)[0]))
        ready = recv_json(ws)
        record = recv_json(ws)
        image = ws.recv(60)
        assert ready["type"] == "ready" and ready["format"] == "jpeg"
        assert record["type"] == "result" and record["index"] == 0 and record["time"] is None
        assert isinstance(image, bytes) and image[:2] == b"\xff\xd8" and decode(image).shape == (240, 320, 3)
        ws.send(json.dumps({"type": "end"}))
        assert closed_with(ws)[0] == 1000


def test_gamma_records_only(server: ServiceServer) -> None:
    with open_stream(server) as ws:
        ws.send(json.dumps({"type": "start", "frames": False}))
        assert recv_json(ws)["frames"] is False
        for f in scene(3):
            ws.send(png(f))
        records = [recv_json(ws) for _ in range(3)]  # JSON only: no binary message in between
        assert [r["index"] for r in records] == [0, 1, 2] and all(r["bytes"] == 0 for r in records)
        ws.send(json.dumps({"type": "end"}))
        assert closed_with(ws)[0] == 1000


def test_a_bordered_picture_is_enhanced_inside_its_field_of_view(server: ServiceServer) -> None:
    """A scope's round field of view on black: by default (``content: auto``) the server finds it on the first
    frame, holds no frame back, records the area on that frame and sends the border back unchanged; with
    ``content: full`` the method sees the whole frame and nothing is recorded."""
    frames = scene(3, 320, 240)
    disc = np.zeros((240, 320), np.uint8)
    cv2.circle(disc, (160, 120), 112, 1, -1)
    bordered = [f * disc[..., None] for f in frames]
    for content in ("auto", "full"):
        with open_stream(server) as ws:
            start: dict[str, Any] = {"type": "start", "format": "png"}
            if content == "full":
                start["content"] = "full"
            ws.send(json.dumps(start))
            assert recv_json(ws)["content"] == content
            records, images = [], []
            for f in bordered:
                ws.send(png(f))
                records.append(recv_json(ws))  # each frame answered before the next is sent: none held back
                image = ws.recv(60)
                assert isinstance(image, bytes)
                images.append(decode(image))
            if content == "auto":
                assert 0.5 < records[0]["content"]["fov_fraction"] < 0.9, records[0]
                assert all("content" not in r for r in records[1:])
                assert all(not im[disc == 0].any() for im in images)  # the border stays black
            else:
                assert all("content" not in r for r in records)
            ws.send(json.dumps({"type": "end"}))
            assert closed_with(ws)[0] == 1000


# ---------------------------------------------------------------------------------------------- a content mask


def scope_mask(w: int = 160, h: int = 120) -> np.ndarray:
    """A scope's mask: a disc of scene (255) on border (0), with a patch of fixed text (128) inside it."""
    mask = np.zeros((h, w), np.uint8)
    cv2.circle(mask, (w // 2, h // 2), h // 2 - 6, 255, -1)
    mask[h // 2 - 4 : h // 2 + 4, w // 2 - 20 : w // 2 + 20] = 128
    return mask


def mask_start(data: bytes | str, name: str = "scope.png", **options: Any) -> str:
    """A start message carrying a content mask: the image file's bytes in base64 (or ``data`` as it is)."""
    text = data if isinstance(data, str) else base64.b64encode(data).decode("ascii")
    return json.dumps({"type": "start", **options, "content_mask": {"name": name, "data": text}})


def test_a_content_mask_in_the_start_message_is_used_as_the_engine_uses_it(
    server: ServiceServer, weights: Path, tmp_path: Path
) -> None:
    """The mask replaces the detection: ready records it by its name and hash (never a server path), every pixel
    outside its scene comes back unchanged, the gammas are the engine's own with the same mask (``colonlight stream
    --content MASK``'s stream), and a frame of another size is one ``bad_frame`` line naming the mask."""
    frames = scene(4)  # texture everywhere: the border is not black, so only the mask can keep it
    mask = scope_mask()
    data = png(np.repeat(mask[..., None], 3, axis=2))
    (tmp_path / "scope.png").write_bytes(data)
    expected_stream = live_content_stream(
        create_method("rnn", weights=str(weights), device="cpu"), load_content_mask(tmp_path / "scope.png")
    )
    expected = [(r.gamma, r.frame) for f in frames for r in expected_stream.push(f)]
    with open_stream(server) as ws:
        ws.send(mask_start(data, name="C:\\masks\\scope.png", format="png"))  # a path: its last part is the name
        ready = recv_json(ws)
        assert ready["type"] == "ready", ready
        assert ready["content"] == {"mask": "scope.png", "sha256": hashlib.sha256(data).hexdigest()}
        got = []
        for f in frames:
            ws.send(png(f))
            record = recv_json(ws)
            image = ws.recv(60)
            assert record["type"] == "result" and isinstance(image, bytes), record
            got.append((record, decode(image)))
        ws.send(png(scene(1, 80, 60)[0]))
        error = recv_json(ws)
        assert error["code"] == "bad_frame" and "\n" not in error["message"], error
        assert error["message"].endswith("frame is 80x60, the content mask scope.png is 160x120"), error
        ws.send(png(frames[0]))  # the stream goes on
        assert recv_json(ws)["index"] == 4 and isinstance(ws.recv(60), bytes)
        ws.send(json.dumps({"type": "end"}))
        code, _, tail = closed_with(ws)
        assert (code, tail[-1]) == (1000, {"type": "end", "frames": 5, "errors": 1})
    outside = mask != 255
    for (record, image), frame, (gamma, engine_frame) in zip(got, frames, expected, strict=True):
        assert np.array_equal(image[outside], frame[outside])  # border and text pixels: the client's own
        assert record["gamma"] == pytest.approx(gamma, abs=1e-5)
        assert np.abs(image.astype(int) - engine_frame).max() <= 1  # PNG: lossless, up to a LUT rounding
    assert not np.array_equal(got[-1][1][~outside], frames[-1][~outside])  # past the seeds, the scene is enhanced


def test_bad_content_masks_close_with_1008_in_one_line(server: ServiceServer) -> None:
    """Each refused mask: one ``error`` line naming it by the client's name (never a server path), then 1008; it is
    counted in ``colonlight_requests_rejected_total`` under the reason a job's upload of it is (none for a mask
    beside another ``content``, a misused option, as for a job)."""
    grey = scope_mask()
    colour = np.repeat(grey[..., None], 3, axis=2)
    colour[..., 0] //= 2
    bad, too_many = "bad_content_mask", "too_many_pixels"
    cases: list[tuple[str, str, str, str | None]] = [
        (
            mask_start("bm90IGEgbWFzaw=!", name="bad.png"),
            "invalid_content_mask",
            "bad.png: its data is not valid base64",
            bad,
        ),
        (
            mask_start(jpeg(np.repeat(grey[..., None], 3, axis=2))),
            "invalid_content_mask",
            "a JPEG content mask is lossy",
            bad,
        ),
        (
            mask_start(png(colour)),
            "invalid_content_mask",
            "scope.png: a content mask is grey (0 border, 255 scene)",
            bad,
        ),
        (mask_start(png(np.zeros((120, 160, 3), np.uint8))), "invalid_content_mask", "no scene pixel (255)", bad),
        (mask_start(b""), "invalid_content_mask", "scope.png: empty file (0 bytes)", bad),
        (
            mask_start(flat_png(8000, 8000, 255), name="huge.png"),
            "frame_too_large",
            "huge.png: it is 8000x8000",
            too_many,
        ),
        (mask_start(png(colour), content="full"), "validation_error", "leave `content` unset (or 'auto')", None),
    ]
    name = 'colonlight_requests_rejected_total{reason="%s"}'
    for start, code, text, reason in cases:
        before = {label: metric(server, name % label) for label in (bad, too_many)}
        with open_stream(server) as ws:
            ws.send(start)
            close, _, messages = closed_with(ws)
            message = messages[-1]["message"]
            assert (close, messages[-1]["code"]) == (1008, code), messages
            assert message.startswith("content mask ") and text in message, message
            assert "\n" not in message and str(server.data_dir) not in message and "/tmp" not in message, message
        counted = {label: metric(server, name % label) - before[label] for label in (bad, too_many)}
        assert counted == {label: float(label == reason) for label in (bad, too_many)}, (text, counted)


def test_a_content_mask_over_the_upload_cap_is_refused_before_it_is_decoded() -> None:
    """Past ``MAX_MASK_BYTES`` (the job upload's cap) a mask is refused unread. Its start message is over 21 MiB,
    past the test server's 1 MiB messages (and the default 16 MiB), so the check is called here as the route calls
    it; the refusal goes out as every other mask refusal above."""
    from colonlight_service.routes.stream import Closing, StreamMask, read_mask
    from colonlight_service.uploads import MAX_MASK_BYTES

    big = base64.b64encode(b"\0" * (MAX_MASK_BYTES + 1)).decode("ascii")
    for data in (big, big + "AAAA" * 4):  # just over, decoded; and over before decoding
        with pytest.raises(Closing) as info:
            read_mask(StreamMask(name="big.pgm", data=data), "auto", 10**8)
        assert (info.value.close_code, info.value.code, info.value.rejected) == (1008, "payload_too_large", "too_large")
        assert info.value.message.startswith(f"content mask big.pgm: larger than {MAX_MASK_BYTES} bytes")


# ---------------------------------------------------------------------------------------------- the key and the cap


def test_api_key_rules(server: ServiceServer) -> None:
    with open_stream(server, key=None) as ws:  # no key at all: the first message is refused
        ws.send(png(scene(1)[0]))
        code, reason, messages = closed_with(ws)
        assert (code, reason, messages[-1]["code"]) == (1008, "unauthorized", "unauthorized")
        assert "API key" in messages[-1]["message"]
    with open_stream(server, key="wrong") as ws:
        ws.send(json.dumps({"type": "start", "api_key": "also wrong"}))
        assert closed_with(ws)[:2] == (1008, "unauthorized")
    with open_stream(server, key=None) as ws:  # a browser: the key in the start message
        ws.send(json.dumps({"type": "start", "api_key": KEY}))
        assert recv_json(ws)["type"] == "ready"


def test_cap_on_concurrent_streams(server: ServiceServer) -> None:
    rejected_before = metric(server, 'colonlight_requests_rejected_total{reason="streams_full"}')
    with open_stream(server) as one, open_stream(server) as two:
        for ws in (one, two):
            ws.send(json.dumps({"type": "start"}))
            assert recv_json(ws)["type"] == "ready"
        with open_stream(server) as three:  # refused at once: its key came in the headers
            code, reason, messages = closed_with(three)
        assert code == 1013 and reason.startswith("busy: 2 streams open")
        assert messages[-1]["code"] == "busy" and "COLONLIGHT_STREAM_MAX" in messages[-1]["message"]
        two.send(json.dumps({"type": "end"}))
        assert closed_with(two)[0] == 1000
        with open_stream(server) as four:  # the place given back is taken again
            four.send(json.dumps({"type": "start"}))
            assert recv_json(four)["type"] == "ready"
    assert metric(server, 'colonlight_requests_rejected_total{reason="streams_full"}') == rejected_before + 1


# ---------------------------------------------------------------------------------------------- bad input


def test_bad_frames_and_messages_are_skipped(server: ServiceServer, weights: Path) -> None:
    good = scene(3)
    bad: list[tuple[bytes | str, str, str]] = [
        (b"GIF89a not ours", "bad_frame", "not a JPEG or PNG image"),
        (b"", "bad_frame", "not a JPEG or PNG image (0 bytes"),
        (jpeg(good[0])[:20], "bad_frame", "truncated JPEG"),
        (png(good[0])[:60], "bad_frame", "could not be decoded"),
        (flat_png(8000, 8000), "bad_frame", "8000x8000 = 64000000 pixels, over the limit"),
        ("not json", "bad_message", "must be a JSON object"),
        (json.dumps({"no": "type"}), "bad_message", 'with a "type"'),
        (json.dumps({"type": "dance"}), "bad_message", "unknown message type 'dance'"),
        (json.dumps({"type": "frame", "time": "noon"}), "bad_message", '"time" must be a finite number'),
        ('{"type": "frame", "time": NaN}', "bad_message", '"time" must be a finite number'),
        (json.dumps({"type": "start"}), "bad_message", "has started already"),
    ]
    rss_before = server_rss(server)
    with open_stream(server) as ws:
        ws.send(json.dumps({"type": "start", "format": "png", "frames": False}))
        assert recv_json(ws)["type"] == "ready"
        ws.send(png(good[0]))
        records = [recv_json(ws)]
        for message, code, text in bad:
            ws.send(message)
            error = recv_json(ws)
            assert error["type"] == "error" and error["code"] == code and text in error["message"], error
        for f in good[1:]:
            ws.send(png(f))
            records.append(recv_json(ws))
        ws.send(json.dumps({"type": "end"}))
        code, _, tail = closed_with(ws)
        assert (code, tail[-1]) == (1000, {"type": "end", "frames": 3, "errors": len(bad)})
    # the stream and its state went on as if the bad messages had not been sent
    assert [r["index"] for r in records] == [0, 1, 2]
    expected = engine_run(weights, good)
    assert [r["gamma"] for r in records] == pytest.approx([g for g, _ in expected], abs=1e-5)
    assert server_rss(server) - rss_before < 100 * 2**20  # the 8000x8000 PNG (192 MB as RGB) was never decoded


def _oversized_frame_close_code(srv: ServiceServer, size: int) -> int | None:
    """Over a raw socket: the upgrade, then only the header (and a few bytes) of a binary message of ``size``
    bytes; the close code the server answers with. Sending the whole message races with the server's close (the
    client still writing can see a reset, which drops the close frame on its side); the header alone cannot."""
    host, port = srv.url.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=30) as sock:
        key = base64.b64encode(os.urandom(16)).decode()
        sock.sendall(
            (
                f"GET /v1/stream HTTP/1.1\r\nHost: {host}:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
                f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nX-API-Key: {KEY}\r\n\r\n"
            ).encode()
        )
        answer = b""
        while b"\r\n\r\n" not in answer:
            chunk = sock.recv(4096)
            assert chunk, answer
            answer += chunk
        assert answer.startswith(b"HTTP/1.1 101"), answer
        rest = answer.split(b"\r\n\r\n", 1)[1]
        mask = os.urandom(4)
        sock.sendall(
            bytes([0x82, 0x80 | 127])
            + struct.pack(">Q", size)
            + mask
            + bytes(b ^ mask[i % 4] for i, b in enumerate(b"\xff\xd8"))
        )
        data = rest
        while True:
            if len(data) >= 2:
                opcode, length = data[0] & 0x0F, data[1] & 0x7F
                if opcode == 0x8 and len(data) >= 2 + length:
                    return int(struct.unpack(">H", data[2:4])[0]) if length >= 2 else None
                if opcode != 0x8 and len(data) >= 2 + length and length < 126:
                    data = data[2 + length :]  # a text message before the close (an error record): skip it
                    continue
            try:
                chunk = sock.recv(4096)
            except OSError:
                return None
            if not chunk:
                return None
            data += chunk


def test_a_message_over_the_size_limit_closes_with_1009(server: ServiceServer) -> None:
    """A frame header announcing more than ``COLONLIGHT_STREAM_MAX_FRAME_MB`` is answered with close code 1009
    before the payload is read, and the server stays healthy."""
    assert _oversized_frame_close_code(server, 2 * 2**20) == 1009  # 2 MiB, over COLONLIGHT_STREAM_MAX_FRAME_MB=1
    assert httpx.get(server.url + "/healthz", timeout=10).status_code == 200


def test_bad_start_options_close_with_1008(server: ServiceServer) -> None:
    for options, text in (
        ({"method": "magic"}, "unknown method 'magic'"),
        ({"quality": 500}, "quality"),
        ({"gamma": 2.0}, "gamma applies only to method gamma"),
        ({"colour": "blue"}, "colour"),
    ):
        with open_stream(server) as ws:
            ws.send(json.dumps({"type": "start", **options}))
            code, reason, messages = closed_with(ws)
            assert code == 1008 and messages[-1]["code"] == "validation_error", messages
            assert text in messages[-1]["message"]


def test_an_idle_stream_is_closed(server: ServiceServer) -> None:
    with open_stream(server) as ws:
        ws.send(json.dumps({"type": "start"}))
        assert recv_json(ws)["type"] == "ready"
        t0 = time.monotonic()
        code, reason, messages = closed_with(ws, timeout=IDLE_S + 20)
        assert code == 1001 and messages[-1]["code"] == "idle" and time.monotonic() - t0 >= IDLE_S - 0.5


# ---------------------------------------------------------------------------------------------- a slow client


def server_rss(srv: ServiceServer) -> int:
    assert srv.proc is not None
    for line in Path(f"/proc/{srv.proc.pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) * 1024
    raise AssertionError("no VmRSS")


def ws_frame(payload: bytes, opcode: int) -> bytes:
    """One masked client frame (RFC 6455 5.2), written by hand so that nothing on our side buffers or reads."""
    n = len(payload)
    head = bytes([0x80 | opcode])
    if n < 126:
        head += bytes([0x80 | n])
    elif n < 65536:
        head += bytes([0x80 | 126]) + struct.pack(">H", n)
    else:
        head += bytes([0x80 | 127]) + struct.pack(">Q", n)
    mask = b"\x5a\xa5\x3c\xc3"
    masked = (np.frombuffer(payload, np.uint8) ^ np.resize(np.frombuffer(mask, np.uint8), n)).tobytes()
    return head + mask + masked


def raw_client(srv: ServiceServer) -> socket.socket:
    """A WebSocket client that never reads after the handshake, with small socket buffers."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 64 * 1024)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 64 * 1024)
    sock.connect(("127.0.0.1", srv.port))
    key = base64.b64encode(b"0123456789abcdef").decode()
    sock.sendall(
        (
            f"GET /v1/stream HTTP/1.1\r\nHost: 127.0.0.1:{srv.port}\r\nUpgrade: websocket\r\n"
            f"Connection: Upgrade\r\nSec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
            f"X-API-Key: {KEY}\r\n\r\n"
        ).encode()
    )
    response = b""
    while b"\r\n\r\n" not in response:
        response += sock.recv(1)  # byte by byte: nothing past the handshake is read
    assert response.startswith(b"HTTP/1.1 101"), response
    return sock


def test_a_client_that_does_not_read_cannot_grow_server_memory(server: ServiceServer) -> None:
    """It sends 640x480 frames as fast as it can and reads nothing: the server answers a few, then stops reading
    (TCP pushes back on the client), its memory stays flat, and after the send timeout it drops the client and
    its place is free again."""
    rng = np.random.default_rng(3)
    frame = ws_frame(png(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)), 0x2)  # ~0.9 MB, incompressible
    assert len(frame) < 2**20
    frames_before = metric(server, "colonlight_frames_processed_total")
    rss_before = server_rss(server)
    sock = raw_client(server)
    try:
        sock.sendall(ws_frame(json.dumps({"type": "start", "format": "png"}).encode(), 0x1))
        sock.settimeout(2.0)
        sent = 0
        try:
            for sent in range(200):  # noqa: B007
                sock.sendall(frame)
        except TimeoutError:
            pass  # the server stopped reading: a send made no progress for 2 s
        assert sent < 60, f"the server kept reading: {sent} frames of 0.9 MB went in unread answers"
        # the frames already read (one waiting message, one being answered) finish, then the server stalls
        answered = metric(server, "colonlight_frames_processed_total") - frames_before
        for _ in range(20):
            time.sleep(1.5)
            now = metric(server, "colonlight_frames_processed_total") - frames_before
            if now == answered:
                break
            answered = now
        assert 0 < answered < 30, answered
        time.sleep(1.0)
        assert metric(server, "colonlight_frames_processed_total") - frames_before == answered  # stalled
        assert server_rss(server) - rss_before < 80 * 2**20
        # once it has read nothing for the send timeout, the client loses its place (2 streams may open again)
        time.sleep(SEND_TIMEOUT_S + 1.0)
        with open_stream(server) as one, open_stream(server) as two:
            for ws in (one, two):
                ws.send(json.dumps({"type": "start"}))
                assert recv_json(ws)["type"] == "ready"
        assert server_rss(server) - rss_before < 80 * 2**20
    finally:
        sock.close()


# ---------------------------------------------------------------------------------------------- the README's client


def test_the_readme_example_client_works(server: ServiceServer, tmp_path: Path) -> None:
    """The client printed in the README, run as a user would, on a clip made here."""
    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text()
    code = readme.split("```python\n# stream_client.py")[1].split("```")[0]
    script = tmp_path / "stream_client.py"
    script.write_text("# stream_client.py" + code)
    clip = make_clip(tmp_path / "clip.mp4", n_frames=12, size=(160, 120))
    env = {**os.environ, "COLONLIGHT_API_KEY": KEY}
    run = subprocess.run(
        [sys.executable, str(script), str(clip), ws_url(server)],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=90,
    )
    assert run.returncode == 0, run.stderr
    lines = [json.loads(line) for line in run.stdout.splitlines()]
    assert lines[0]["type"] == "ready" and lines[-1] == {"type": "end", "frames": 12, "errors": 0}
    results = lines[1:-1]
    assert [r["index"] for r in results] == list(range(12))
    assert [r["time"] for r in results] == pytest.approx([i / 25 for i in range(12)])
    written = sorted(tmp_path.glob("enhanced_*.jpg"))
    assert len(written) == 12 and decode(written[-1].read_bytes()).shape == (120, 160, 3)


def test_stopping_the_server_closes_open_streams(tmp_path: Path) -> None:
    """SIGTERM with a stream open: the client is told (1012, service restart) and the server exits cleanly."""
    srv = ServiceServer(tmp_path / "data", {"COLONLIGHT_METHOD": "gamma", "COLONLIGHT_WORKERS": "1"})
    srv.start(timeout=START_TIMEOUT_S)
    try:
        with connect(ws_url(srv), proxy=None, max_size=None, compression=None, open_timeout=20) as ws:
            ws.send(json.dumps({"type": "start", "gamma": 0.5, "format": "png"}))
            assert recv_json(ws)["method"] == "gamma"
            f = scene(1)[0]
            ws.send(png(f))
            assert recv_json(ws)["gamma"] == 0.5 and isinstance(ws.recv(30), bytes)
            t0 = time.monotonic()
            assert srv.proc is not None
            srv.proc.terminate()
            code, _, _ = closed_with(ws)
            assert code == 1012 and time.monotonic() - t0 < 10
        assert srv.proc.wait(20) in (0, -15)  # uvicorn re-raises SIGTERM after its graceful shutdown
    finally:
        srv.stop()
    assert "Traceback" not in srv.log(), srv.log()


def test_a_jpeg_turned_by_its_exif_orientation_is_read_as_a_frame_folder_reads_it(tmp_path: Path) -> None:
    """A phone's JPEG (EXIF orientation 6: turn 90 degrees) decodes with its header's sides swapped; the stream
    refused it as "corrupt or truncated". It is now the engine's frame, upright, as ``enhance`` reads a file."""
    from io import BytesIO

    from colonlight_service.stream_frames import decode_frame
    from PIL import Image

    from colonlight.frames import read_image

    image = Image.fromarray(np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8))
    exif = image.getexif()
    exif[0x0112] = 6  # Orientation: rotate 90 CW to display
    buf = BytesIO()
    image.save(buf, "JPEG", exif=exif.tobytes())
    (tmp_path / "phone.jpg").write_bytes(buf.getvalue())
    frame = decode_frame(buf.getvalue(), 10**6)
    assert frame.shape == (64, 48, 3)
    np.testing.assert_array_equal(frame, read_image(tmp_path / "phone.jpg"))
