"""An uploaded content mask (the ``content_mask`` part beside ``file``) against a real ``colonlight serve``: used as
``colonlight enhance --content MASK`` uses it (same gammas and frames, border pixels unchanged), recorded by its
upload name and hash, refused in one line naming it when it is no usable mask (nothing left on the server), and
a mask of another size than the clip's frames fails the job in one line naming the mask; a queued job keeps its
mask across a restart."""

from __future__ import annotations

import hashlib
import io
import json
import zipfile
from collections.abc import Iterator
from fractions import Fraction
from pathlib import Path

import av
import cv2
import httpx
import numpy as np
import pytest
from colonlight_cli.main import app as cli_app
from typer.testing import CliRunner

from ..media import needs_ffmpeg
from ..service_server import ServiceServer
from .test_service import assert_json_error, leftovers, wait_done

pytestmark = [needs_ffmpeg, pytest.mark.timeout(120)]

WIDTH, HEIGHT = 128, 96
#: The field of view inside the black border: rows, columns.
FOV = (slice(12, 84), slice(20, 108))
#: The module server's pixel cap: far above the clip's frames, below a mask made too large for it.
MAX_PIXELS = 1_000_000


def bordered_frames(n: int) -> list[np.ndarray]:
    """Frames of a moving, textured scene inside a black border (a scope's picture, simplified)."""
    rng = np.random.default_rng(5)
    base = rng.integers(40, 200, size=(HEIGHT, WIDTH, 3), dtype=np.uint8)
    frames = []
    for i in range(n):
        frame = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
        frame[FOV] = np.roll(base, 3 * i, axis=1)[FOV]
        frames.append(frame)
    return frames


def write_clip(path: Path, frames: list[np.ndarray], fps: int = 12) -> Path:
    with av.open(str(path), mode="w") as out:
        stream = out.add_stream("libx264", rate=Fraction(fps))
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.options = {"preset": "ultrafast", "crf": "12"}
        for frame in frames:
            out.mux(stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")))
        out.mux(stream.encode())
    return path


def decoded(path: Path) -> list[np.ndarray]:
    with av.open(str(path)) as c:
        return [f.to_ndarray(format="rgb24") for f in c.decode(video=0)]


def pgm(image: np.ndarray) -> bytes:
    return f"P5\n{image.shape[1]} {image.shape[0]}\n255\n".encode() + image.tobytes()


@pytest.fixture(scope="module")
def media(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("mask-media")
    mask = np.zeros((HEIGHT, WIDTH), np.uint8)
    mask[FOV] = 255
    (d / "scope.pgm").write_bytes(pgm(mask))
    (d / "scope.jpg").write_bytes(cv2.imencode(".jpg", mask)[1].tobytes())
    (d / "small.png").write_bytes(cv2.imencode(".png", mask[::2, ::2])[1].tobytes())
    (d / "huge.png").write_bytes(cv2.imencode(".png", np.zeros((1000, 1001), np.uint8))[1].tobytes())
    return {
        "clip": write_clip(d / "scope clip.mp4", bordered_frames(12)),
        "pgm": d / "scope.pgm",
        "jpg": d / "scope.jpg",
        "small": d / "small.png",
        "huge": d / "huge.png",
    }


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("service-mask") / "data"
    env = {
        "COLONLIGHT_WEIGHTS": str(random_weights),
        "COLONLIGHT_WORKERS": "1",
        "COLONLIGHT_SYNC_MAX_SECONDS": "3",
        "COLONLIGHT_MAX_PIXELS": str(MAX_PIXELS),
    }
    with ServiceServer(data, env) as srv:
        yield srv


def post(client: httpx.Client, route: str, clip: Path, mask: Path, **fields: str) -> httpx.Response:
    files = {"file": (clip.name, clip.read_bytes(), "video/mp4"), "content_mask": (mask.name, mask.read_bytes())}
    return client.post(route, files=files, data={"fps": "0", **fields})


def zipped_frames(client: httpx.Client, url: str) -> dict[str, bytes]:
    with zipfile.ZipFile(io.BytesIO(client.get(url).content)) as zf:
        return {Path(name).name: zf.read(name) for name in zf.namelist()}


def test_an_uploaded_mask_is_used_as_enhance_uses_it(
    client: httpx.Client, server: ServiceServer, media: dict[str, Path], tmp_path: Path, random_weights: Path
) -> None:
    """The job's gammas and frames are byte for byte the CLI's with the same mask; the border is the source's;
    the job and its gammas.json record the mask by its upload name and SHA-256; POST /v1/enhance agrees."""
    clip, mask = media["clip"], media["pgm"]
    r = post(client, "/v1/jobs", clip, mask)
    assert r.status_code == 202, r.text
    digest = hashlib.sha256(mask.read_bytes()).hexdigest()
    assert r.json()["options"]["content"] == {"mask": "scope.pgm", "sha256": digest}
    done = wait_done(client, r.headers["location"])
    assert done["status"] == "succeeded", done
    served = client.get(done["links"]["gammas"]).json()
    assert served["settings"]["content"] == {"mask": "scope.pgm", "sha256": digest}
    assert str(server.data_dir) not in json.dumps(served)
    frames = zipped_frames(client, done["links"]["frames"])

    cli = [
        *("enhance", str(clip), "-o", str(tmp_path), "--weights", str(random_weights), "--device", "cpu"),
        *("--fps", "0", "--content", str(mask), "--video", "-q"),
    ]
    result = CliRunner().invoke(cli_app, cli)
    assert result.exit_code == 0, result.output
    out = tmp_path / clip.stem
    local = json.loads((out / "gammas.json").read_text())
    assert served["frames"] == local["frames"] and len(served["frames"]) == 12
    assert {f["gamma"] for f in served["frames"]} != {1.0}  # the method did change the scene
    assert local["settings"]["content"] == {"mask": str(mask), "sha256": digest}
    assert frames == {p.name: p.read_bytes() for p in sorted((out / "frames").iterdir())}

    border = np.ones((HEIGHT, WIDTH), bool)
    border[FOV] = False
    for source, name, record in zip(decoded(clip), sorted(frames), served["frames"], strict=True):
        enhanced = cv2.imdecode(np.frombuffer(frames[name], np.uint8), cv2.IMREAD_COLOR)[..., ::-1]
        assert np.array_equal(enhanced[border], source[border])  # the border is written unchanged
        assert np.array_equal(enhanced[FOV], source[FOV]) == (record["gamma"] == 1.0)

    now = post(client, "/v1/enhance", clip, mask)
    assert now.status_code == 200, now.text
    assert now.json()["gammas"]["frames"] == local["frames"]
    assert now.json()["gammas"]["settings"]["content"] == {"mask": "scope.pgm", "sha256": digest}
    assert list((server.data_dir / "sync").iterdir()) == [] and leftovers(server) == []


def refused_on_both_routes(
    client: httpx.Client, server: ServiceServer, clip: Path, mask: Path, status: int, **fields: str
) -> list[str]:
    """The one-line messages of ``status`` that both upload routes give ``mask``; none names a server path."""
    messages = []
    for route in ("/v1/jobs", "/v1/enhance"):
        body = assert_json_error(post(client, route, clip, mask, **fields), status)
        assert "\n" not in body["message"] and str(server.data_dir) not in body["message"], body
        messages.append(f"{body['code']}: {body['message']}")
    return messages


def assert_nothing_left(server: ServiceServer, jobs_before: list[Path]) -> None:
    assert leftovers(server) == [] and list((server.data_dir / "sync").iterdir()) == []
    assert sorted((server.data_dir / "jobs").iterdir()) == jobs_before


def test_a_jpeg_mask_is_refused_naming_it_with_nothing_left(
    client: httpx.Client, server: ServiceServer, media: dict[str, Path]
) -> None:
    jobs_before = sorted((server.data_dir / "jobs").iterdir())
    for message in refused_on_both_routes(client, server, media["clip"], media["jpg"], 422):
        assert message.startswith("invalid_content_mask: ") and "scope.jpg" in message and "JPEG" in message
    both = assert_json_error(post(client, "/v1/jobs", media["clip"], media["pgm"], content="full"), 422)
    assert "scope.pgm" in both["message"] and "content" in both["message"]
    assert_nothing_left(server, jobs_before)


def test_a_mask_over_the_pixel_cap_is_413_naming_it_with_nothing_left(
    client: httpx.Client, server: ServiceServer, media: dict[str, Path]
) -> None:
    """Judged from the PNG's header (a few KiB of bytes can declare a bomb), before anything is decoded."""
    jobs_before = sorted((server.data_dir / "jobs").iterdir())
    for message in refused_on_both_routes(client, server, media["clip"], media["huge"], 413):
        assert "huge.png" in message and "1001x1000" in message, message
    assert_nothing_left(server, jobs_before)


def test_a_mask_of_another_size_fails_the_job_in_one_line(
    client: httpx.Client, server: ServiceServer, media: dict[str, Path]
) -> None:
    r = post(client, "/v1/jobs", media["clip"], media["small"])
    assert r.status_code == 202, r.text
    done = wait_done(client, r.headers["location"])
    assert done["status"] == "failed"
    error = done["error"]
    assert "small.png" in error and "64x48" in error and "\n" not in error, error
    assert str(server.data_dir) not in error and "<data>" not in error
    job_dir = server.data_dir / "jobs" / done["id"]
    assert sorted(p.name for p in job_dir.iterdir() if p.is_file()) == []  # the upload and its mask are gone


def test_the_openapi_body_lists_the_optional_mask_part(client: httpx.Client) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    for route in ("/v1/jobs", "/v1/enhance"):
        form = paths[route]["post"]["requestBody"]["content"]["multipart/form-data"]
        part = form["schema"]["properties"]["content_mask"]
        assert part["type"] == "string" and part["format"] == "binary" and "PGM" in part["description"]
        assert form["schema"]["required"] == ["file"] and "content_mask" in form["encoding"]


def test_a_job_resumed_after_a_restart_keeps_its_mask(
    server: ServiceServer, media: dict[str, Path], tmp_path: Path
) -> None:
    """A queued job's mask lives in its folder: the server killed before the job ran (its one worker busy with
    another clip), the job resumes at the next start with its mask. Last here: it restarts the module's server."""
    blocker = write_clip(tmp_path / "blocker.mp4", bordered_frames(96))
    with httpx.Client(base_url=server.url, timeout=60) as c:
        first = c.post("/v1/jobs", files={"file": ("b.mp4", blocker.read_bytes())}, data={"fps": "0"})
        assert first.status_code == 202, first.text
        r = post(c, "/v1/jobs", media["clip"], media["pgm"])
        assert r.status_code == 202, r.text
        lost = post(c, "/v1/jobs", media["clip"], media["pgm"])  # its mask is deleted while the server is down
        assert lost.status_code == 202, lost.text
        assert c.get(r.headers["location"]).json()["status"] == "queued"
        server.kill()
    job_dir = server.data_dir / "jobs" / r.json()["id"]
    assert (job_dir / "content_mask").read_bytes() == media["pgm"].read_bytes()
    (server.data_dir / "jobs" / lost.json()["id"] / "content_mask").unlink()
    server.start()
    with httpx.Client(base_url=server.url, timeout=60) as c:
        assert c.delete(first.headers["location"]).status_code == 204  # the mask's job need not wait for it
        done = wait_done(c, r.headers["location"])
        assert done["status"] == "succeeded" and done["note"] == "resumed after a server restart", done
        assert done["attempts"] == 1  # it had not started before the kill
        digest = hashlib.sha256(media["pgm"].read_bytes()).hexdigest()
        assert c.get(done["links"]["gammas"]).json()["settings"]["content"] == {"mask": "scope.pgm", "sha256": digest}
        gone = c.get(lost.headers["location"]).json()  # failed at the start, saying why; never run without its mask
        assert gone["status"] == "failed", gone
        assert "content mask scope.pgm is gone" in gone["error"] and "\n" not in gone["error"], gone
