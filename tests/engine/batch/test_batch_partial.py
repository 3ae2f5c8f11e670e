"""A clip that fails part way leaves nothing half-written: the frames (and video) it had already published are
removed, its manifest entry is ``failed`` naming the cause, in the CLI batch and in the service. Before, a
recording whose frame size changes after 40 frames (two recordings joined, ``cat a.ts b.ts``) left 29 frames in
``OUT/clip/frames/`` beside its ``failed`` entry."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest
from colonlight_cli.main import app
from typer.testing import CliRunner

from tests.service.test_service import wait_done

from ...media import ffmpeg_exe, joined, make_clip, needs_ffmpeg
from ...service_server import ServiceServer

pytestmark = needs_ffmpeg


@pytest.fixture(scope="module")
def resized(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """40 frames of 128x96, then 40 of 160x120: decodes fine up to frame 40, then fails (the size changes)."""
    if ffmpeg_exe() is None:
        pytest.skip("imageio-ffmpeg's ffmpeg binary is not available")
    d = tmp_path_factory.mktemp("resized")
    parts = [make_clip(d / "a.ts", 40, 25), make_clip(d / "b.ts", 40, 25, size=(160, 120), first_index=100)]
    return joined(parts, d / "resized.ts")


def files(folder: Path) -> list[str]:
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.exists() else []


@pytest.mark.parametrize("workers", ["1", "2"])
def test_batch_removes_the_frames_of_a_clip_that_fails_part_way(resized: Path, tmp_path: Path, workers: str) -> None:
    videos = tmp_path / "videos"
    videos.mkdir()
    (videos / "resized.ts").write_bytes(resized.read_bytes())
    make_clip(videos / "good.mp4", 30, 25)
    out = tmp_path / "out"
    args = ["enhance", str(videos), "-o", str(out), "--method", "none", "--video", "-q", "-j", workers]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 1, result.output
    failed = [line for line in result.output.splitlines() if line.startswith("failed")]
    assert len(failed) == 1 and str(videos / "resized.ts") in failed[0] and "frame size changes" in failed[0]
    assert files(out / "resized") == []  # not a frame, not a video, not a temporary, no empty folder
    assert not (out / "resized").exists()
    entries = {c["clip"]: c for c in json.loads((out / "manifest.json").read_text())["clips"]}
    assert entries["resized"]["status"] == "failed" and "frame size changes" in entries["resized"]["error"]
    assert entries["good"]["status"] == "done" and (out / "good" / "gammas.json").is_file()


def test_failure_part_way_after_a_complete_run_with_other_settings(resized: Path, tmp_path: Path) -> None:
    """An earlier complete output of the clip (other settings) is not left behind as if it were this run's."""
    videos = tmp_path / "videos"
    videos.mkdir()
    clip = videos / "clip.ts"
    make_clip(clip, 40, 25)  # complete output at every frame
    out = tmp_path / "out"
    first = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q", "--fps", "0"])
    assert first.exit_code == 0 and (out / "clip" / "gammas.json").is_file(), first.output
    clip.write_bytes(resized.read_bytes())  # the same name now fails part way
    second = CliRunner().invoke(app, ["enhance", str(videos), "-o", str(out), "--method", "none", "-q"])
    assert second.exit_code == 1, second.output
    assert files(out / "clip") == []


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    data = tmp_path_factory.mktemp("partial-server") / "data"
    env = {"COLONLIGHT_WEIGHTS": str(random_weights), "COLONLIGHT_WORKERS": "1"}
    with ServiceServer(data, env) as srv:
        yield srv


@pytest.mark.timeout(240)
def test_service_job_that_fails_part_way_keeps_no_frames(resized: Path, server: ServiceServer) -> None:
    with httpx.Client(base_url=server.url, timeout=120) as client:
        r = client.post(
            "/v1/jobs",
            files={"file": ("resized.ts", resized.read_bytes(), "video/mp2t")},
            data={"method": "none"},
        )
        assert r.status_code == 202, r.text
        job = wait_done(client, r.headers["location"], timeout=120)
        assert job["status"] == "failed" and "frame size changes" in job["error"], job
        assert str(server.data_dir) not in job["error"]
        job_dir = server.data_dir / "jobs" / job["id"]
        left = [f for f in files(job_dir) if f.startswith("out/") or f.endswith((".png", ".jpg", ".mp4"))]
        assert left == [], left
        assert client.get(r.json()["links"]["gammas"]).status_code in (404, 409, 410)
