"""The web page's live mode in a real headless Chromium (Debian's, driven by Playwright) against a real server:
Chromium's fake camera (``--use-fake-device-for-media-stream``) and then a video file, streamed frame by frame
through ``/v1/stream``, with the API key typed into the page.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest

from ..service_server import ServiceServer
from .test_service_browser import ARGS, CHROMIUM, endoscopy_like_clip

KEY = "k3y"
FAKE_MEDIA = ["--use-fake-device-for-media-stream", "--use-fake-ui-for-media-stream"]

#: Bound on each wait for the page, in ms. Every wait is for a real condition (a status, a frame count), so on an idle
#: machine the test takes seconds; the bound only has to hold at a load of 15 on 2 cores, where a frame's round
#: trip can take several seconds (the test timed out at 60 s under load 8-14).
WAIT_MS = 300_000

pytestmark = [
    pytest.mark.timeout(4 * WAIT_MS // 1000),
    pytest.mark.skipif(not CHROMIUM.is_file(), reason=f"no Chromium at {CHROMIUM} (apt-get install chromium)"),
]
sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed (pip install playwright)")


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory, random_weights: Path) -> Iterator[ServiceServer]:
    env = {"COLONLIGHT_WEIGHTS": str(random_weights), "COLONLIGHT_WORKERS": "1", "COLONLIGHT_API_KEY": KEY}
    srv = ServiceServer(tmp_path_factory.mktemp("live") / "data", env).start(timeout=180)  # slow on a busy machine
    try:
        yield srv
    finally:
        srv.stop()


def frames_processed(srv: ServiceServer) -> int:
    text = httpx.get(srv.url + "/metrics", headers={"X-API-Key": KEY}, timeout=10).text
    return int(
        float(
            next(line for line in text.splitlines() if line.startswith("colonlight_frames_processed_total")).split()[1]
        )
    )


CANVAS_MEAN = """() => { const c = document.querySelector('#live-out');
  const d = c.getContext('2d').getImageData(0, 0, c.width, c.height).data;
  let s = 0; for (let i = 0; i < d.length; i += 4) s += d[i] + d[i + 1] + d[i + 2];
  return s / (d.length / 4) / 3; }"""


def test_live_mode_streams_the_camera_and_a_file(server: ServiceServer, tmp_path: Path) -> None:
    # 10 s at 24 fps, 320x240: long enough that even a busy server answers several frames while it plays
    clip = endoscopy_like_clip(tmp_path / "scope.mp4", n=240)
    with sync_api.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=str(CHROMIUM), args=ARGS + FAKE_MEDIA, headless=True)
        try:
            page = browser.new_page(viewport={"width": 1280, "height": 1000})
            page.set_default_timeout(WAIT_MS)
            errors: list[str] = []
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.goto(server.url + "/#live")
            assert page.is_visible("#live") and not page.is_visible("#drop")
            page.wait_for_selector("#key-row:not([hidden])")
            page.fill("#apikey", KEY)
            page.dispatch_event("#apikey", "change")
            page.wait_for_function("document.querySelector('#method').options.length > 0")

            # the fake camera: frames go out, enhanced frames come back and are drawn, the gamma plot grows
            before = frames_processed(server)
            page.click("#live-camera")
            page.wait_for_function("document.querySelector('#live-status').dataset.status === 'live'")
            page.wait_for_function("Number(document.querySelector('#live-out').dataset.frames) >= 12")
            assert page.eval_on_selector("#live-out", "c => [c.width, c.height]") == [640, 480]  # the fake device
            assert page.evaluate(CANVAS_MEAN) > 5  # a picture, not a black canvas
            assert int(page.eval_on_selector("#live-plot", "s => s.dataset.points")) >= 12
            assert "fps" in page.inner_text("#live-stats") and "γ" in page.inner_text("#live-gamma")
            page.click("#live-stop")
            page.wait_for_function("document.querySelector('#live-status').dataset.status === 'done'")
            shown = int(page.eval_on_selector("#live-out", "c => c.dataset.frames"))
            assert frames_processed(server) - before >= shown >= 12
            assert page.eval_on_selector("#live-source", "v => v.srcObject.getVideoTracks()[0].readyState") == "ended"

            # a video file: played, streamed while it plays, and the stream ends with the file
            page.set_input_files("#live-file", str(clip))
            page.wait_for_function("document.querySelector('#live-status').dataset.status === 'live'")
            page.wait_for_function("document.querySelector('#live-status').dataset.status === 'done'")
            sent = int(page.eval_on_selector("#live-out", "c => c.dataset.frames"))
            assert 4 <= sent <= 10 * 18 + 1  # at most 18 fps of a 10 s file; fewer when the server is busy
            assert page.eval_on_selector("#live-out", "c => [c.width, c.height]") == [320, 240]
            assert page.inner_text("#error") == ""

            # the form's content mask goes with the stream: one of another size than the camera's 640x480 frames
            # is named in each frame's error (so the server has it), one of their size is used without a word
            for name, (w, h) in (("wrong.pgm", (64, 48)), ("scope.pgm", (640, 480))):
                mask = np.zeros((h, w), np.uint8)
                mask[h // 8 : h - h // 8, w // 8 : w - w // 8] = 255
                (tmp_path / name).write_bytes(b"P5\n%d %d\n255\n" % (w, h) + mask.tobytes())
                page.set_input_files("#mask", str(tmp_path / name))
                page.click("#live-camera")
                page.wait_for_function("document.querySelector('#live-status').dataset.status === 'live'")
                if name == "wrong.pgm":
                    page.wait_for_function("document.querySelector('#error').textContent.includes('wrong.pgm')")
                    assert "640x480" in page.inner_text("#error") and "64x48" in page.inner_text("#error")
                else:
                    page.wait_for_function("Number(document.querySelector('#live-out').dataset.frames) >= 4")
                    assert page.inner_text("#error") == ""
                page.click("#live-stop")
                page.wait_for_function("document.querySelector('#live-status').dataset.status === 'done'")
                page.evaluate("() => showError('')")
            assert not errors, errors
            page.screenshot(path=str(tmp_path / "live.png"), full_page=True)
        finally:
            browser.close()
    assert "Traceback" not in server.log()
