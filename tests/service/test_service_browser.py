"""The web page in a real headless Chromium (Debian's, driven by Playwright): drop a clip, watch the job finish,
check that the enhanced H.264 video actually plays and the gamma curve is drawn, and take a screenshot.

Set COLONLIGHT_UPDATE_SCREENSHOT=1 to write the screenshot to docs/service_screenshot.png.
"""

from __future__ import annotations

import base64
import math
import os
import shutil
from collections.abc import Iterator
from pathlib import Path

import av
import httpx
import numpy as np
import pytest

from ..service_server import ServiceServer

CHROMIUM = Path(os.environ.get("COLONLIGHT_CHROMIUM", "/usr/bin/chromium"))
REPO = Path(__file__).resolve().parents[2]
ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--autoplay-policy=no-user-gesture-required",
]

pytestmark = [
    pytest.mark.timeout(180),
    pytest.mark.skipif(not CHROMIUM.is_file(), reason=f"no Chromium at {CHROMIUM} (apt-get install chromium)"),
]
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")


def endoscopy_like_clip(path: Path, n: int = 72, fps: float = 24.0, size: tuple[int, int] = (320, 240)) -> Path:
    """A dark tunnel with folds and a light source whose strength swings, as colonoscopy lighting does;
    written with the engine's H.264 writer."""
    from colonlight.video import VideoWriter

    w, h = size
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    with VideoWriter(path, fps=fps) as writer:
        for i in range(n):
            cx, cy = w / 2 + 25 * math.sin(i / 11), h / 2 + 12 * math.cos(i / 17)
            r = np.hypot(x - cx, y - cy) / (0.5 * math.hypot(w, h))
            folds = 0.55 + 0.45 * np.sin(r * 38 - i * 0.35)
            lum = np.clip(r * 1.7, 0, 1) ** 0.9 * (0.55 + 0.45 * folds)
            gain = 0.5 + 0.38 * math.sin(2 * math.pi * i / 48)
            rgb = lum[..., None] * np.array([235, 125, 110], np.float32) * gain
            writer.write(np.clip(rgb, 0, 255).astype(np.uint8))
    return path


def generated_clip(path: Path) -> Path:
    """A 3-second clip from colonlight's own generator (held-out settings, disturbed lighting, 30 fps), as
    ``colonlight demo`` renders it: what the README's screenshot shows (no frames of anyone else's data)."""
    from colonlight.synth import SYNTH_VIDEO, SynthConfig, write_clip

    seed = 20210628
    cfg = SynthConfig.sample(
        np.random.default_rng(seed), split="heldout", width=480, height=384, n_frames=90, fps=30.0,
        undisturbed_seeds=True,
    )  # fmt: skip
    write_clip(path.parent / "synth", cfg, seed=seed, video=True, frames=False)
    shutil.move(path.parent / "synth" / SYNTH_VIDEO, path)
    return path


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[ServiceServer]:
    """The shipped default model, as a user's server runs it (the README's screenshot shows it)."""
    data = tmp_path_factory.mktemp("browser") / "data"
    with ServiceServer(data, {"COLONLIGHT_WORKERS": "1"}) as srv:
        yield srv


def test_drop_a_clip_and_watch_it(server: ServiceServer, tmp_path: Path) -> None:
    clip = generated_clip(tmp_path / "colonoscopy clip.mp4")
    shot = tmp_path / "service_screenshot.png"
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1040})
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url + "/")
            page.wait_for_function("document.querySelector('#method').options.length > 0")
            assert page.eval_on_selector("#method", "s => s.value") == "rnn"
            # a real drop event carrying the file, as when a person drags the clip onto the page
            page.evaluate(
                """([b64, name]) => {
                    const bytes = Uint8Array.from(atob(b64), c => c.charCodeAt(0));
                    const dt = new DataTransfer();
                    dt.items.add(new File([bytes], name, {type: 'video/mp4'}));
                    const drop = new DragEvent('drop', {dataTransfer: dt, bubbles: true, cancelable: true});
                    document.querySelector('#drop').dispatchEvent(drop);
                }""",
                [base64.b64encode(clip.read_bytes()).decode(), clip.name],
            )
            page.wait_for_function(
                "['running', 'queued', 'succeeded'].includes(document.querySelector('#status').dataset.status)"
            )
            page.wait_for_function("document.querySelector('#status').dataset.status === 'succeeded'", timeout=90_000)
            page.wait_for_function("Number(document.querySelector('#plot').dataset.points || 0) > 0")
            points = int(page.eval_on_selector("#plot", "s => s.dataset.points"))
            job_id = page.evaluate("location.hash").removeprefix("#job=")
            job = httpx.get(f"{server.url}/v1/jobs/{job_id}").json()
            assert job["status"] == "succeeded" and points == job["frames_done"] == 54  # 3 s at 18 fps
            n_vertices = page.eval_on_selector("#gamma-line", "l => l.getAttribute('points').trim().split(' ').length")
            assert n_vertices == points
            assert page.eval_on_selector("#gamma-line", "l => l.getBBox().width") > 500  # drawn across the plot

            # the enhanced H.264 clip really plays: metadata, decoded frames, and the clock advancing
            page.wait_for_function("document.querySelector('#enhanced').readyState >= 2", timeout=30_000)
            with av.open(str(clip)) as src:
                width = src.streams.video[0].codec_context.width
            assert page.eval_on_selector("#enhanced", "v => v.videoWidth") == width
            assert page.eval_on_selector("#enhanced", "v => Math.round(v.duration)") == 3
            page.click("#play-both")
            page.wait_for_function("document.querySelector('#enhanced').currentTime > 1.0", timeout=30_000)
            assert page.eval_on_selector("#enhanced", "v => v.error") is None
            page.wait_for_function("document.querySelector('#original').currentTime > 0.5", timeout=30_000)
            decoded = page.eval_on_selector("#enhanced", "v => v.getVideoPlaybackQuality().totalVideoFrames")
            assert decoded > 5
            # the playhead follows the video; pause mid-clip for the picture
            page.evaluate(
                """() => { for (const v of document.querySelectorAll('video')) { v.pause(); v.currentTime = 1.6; } }"""
            )
            page.wait_for_function(
                "Math.abs(document.querySelector('#enhanced').currentTime - 1.6) < 0.05 && "
                "document.querySelector('#enhanced').readyState >= 2"
            )
            page.wait_for_function("document.querySelector('#gamma-now').textContent.includes('γ')")
            page.wait_for_timeout(300)
            assert float(page.eval_on_selector("#playhead", "l => l.getAttribute('x1')")) > 100
            assert not errors, errors
            page.screenshot(path=str(shot), full_page=True)
        finally:
            browser.close()
    assert shot.stat().st_size > 20_000
    if os.environ.get("COLONLIGHT_UPDATE_SCREENSHOT"):
        (REPO / "docs").mkdir(exist_ok=True)
        shutil.copy(shot, REPO / "docs" / "service_screenshot.png")


def test_page_with_an_api_key(tmp_path: Path, random_weights: Path) -> None:
    """With COLONLIGHT_API_KEY the page asks for the key, sends it, and plays the video fetched with it; a content
    mask chosen on the page goes with the clip, and the job records it by its file name."""
    from colonlight.content_area import ContentArea
    from colonlight.content_mask import write_content_mask

    clip = endoscopy_like_clip(tmp_path / "dark.mp4", n=36)
    scene = np.zeros((240, 320), bool)
    scene[20:220, 30:290] = True
    write_content_mask(tmp_path / "scope.pgm", ContentArea(scene, np.zeros_like(scene)))
    env = {"COLONLIGHT_WEIGHTS": str(random_weights), "COLONLIGHT_WORKERS": "1", "COLONLIGHT_API_KEY": "k3y"}
    with ServiceServer(tmp_path / "data", env) as srv, sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS, headless=True)
        try:
            page = browser.new_page()
            page.goto(srv.url + "/")
            page.wait_for_selector("#key-row:not([hidden])")
            assert "API key" in page.inner_text("#error")
            page.fill("#apikey", "k3y")
            page.dispatch_event("#apikey", "change")
            page.wait_for_function("document.querySelector('#method').options.length > 0")
            page.set_input_files("#mask", str(tmp_path / "scope.pgm"))
            page.set_input_files("#file", str(clip))  # the click-to-choose path
            page.wait_for_function("document.querySelector('#status').dataset.status === 'succeeded'", timeout=90_000)
            job_id = page.evaluate("location.hash").removeprefix("#job=")
            job = httpx.get(f"{srv.url}/v1/jobs/{job_id}", headers={"X-API-Key": "k3y"}).json()
            assert job["options"]["content"]["mask"] == "scope.pgm", job
            page.wait_for_function("document.querySelector('#enhanced').src.startsWith('blob:')")
            page.wait_for_function("document.querySelector('#enhanced').readyState >= 2", timeout=30_000)
            page.evaluate("document.querySelector('#enhanced').play()")
            page.wait_for_function("document.querySelector('#enhanced').currentTime > 0.5", timeout=30_000)
            assert int(page.eval_on_selector("#plot", "s => s.dataset.points")) == 27  # 1.5 s at 18 fps
        finally:
            browser.close()
