"""A sixth hostile-input sweep of the CLI, through real ``colonlight`` processes on real files (the engine's side
is tests/engine/test_hostile_sweep6.py):

* ``colonlight stream CLIP -o OUT --timeout inf`` (or ``1e308``) enhanced the clip, then ended with an
  OverflowError traceback ("timestamp out of range for platform time_t", from the reader thread's
  ``join(timeout + 1)``), exit 1 and no ``stream.json``. It is now a usage error before anything is written.
* ``colonlight enhance`` of a folder of float TIFF frames holding NaN printed numpy's "RuntimeWarning: invalid
  value encountered in cast" (and its line of source) once per frame; a folder of one-channel float TIFFs failed
  as "not a readable image (corrupt or unsupported format)" under OpenCV's own "[ERROR:...] imdecode_" line.
  Both are now enhanced, with one line each.
* ``--camera`` with a size written in Arabic-Indic digits was accepted and copied beside every clip (COLMAP
  cannot read it); it is now one line naming the file, before any work.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image

from ..commands import run_colonlight
from ..media import make_clip, needs_ffmpeg

pytestmark = [needs_ffmpeg, pytest.mark.timeout(300)]

GAMMA = ("--method", "gamma", "-q", "-j", "1")


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return make_clip(tmp_path_factory.mktemp("clip") / "a.mp4", 8, size=(64, 48))


_TIMEOUT_RANGE = "timeout must be a number of seconds above 0 and at most 1000000000"


@pytest.mark.parametrize(
    ("option", "value", "message"),
    [
        ("--timeout", "inf", _TIMEOUT_RANGE),
        ("--timeout", "1e308", _TIMEOUT_RANGE),
        # read nothing and failed at run time (exit 1) as a stream that gave no frame
        ("--duration", "0", "duration must be a number of seconds above 0, got 0.0"),
    ],
)
def test_a_stream_timeout_or_duration_out_of_range_is_a_usage_error(
    clip: Path, tmp_path: Path, option: str, value: str, message: str
) -> None:
    out = tmp_path / "live"
    code, output = run_colonlight("stream", str(clip), "-o", str(out), "-m", "gamma", option, value)
    assert code == 2, output
    assert message in output, output
    assert not out.exists()


def test_float_tiff_frames_with_nan_or_one_channel_are_enhanced_quietly(clip: Path, tmp_path: Path) -> None:
    inputs = tmp_path / "in"
    nan, grey = inputs / "nan", inputs / "grey"
    nan.mkdir(parents=True)
    grey.mkdir()
    for i in range(3):
        bgr = np.full((48, 64, 3), 0.25 + 0.1 * i, np.float32)
        bgr[:4, :4] = np.nan
        bgr[4:8, :4] = np.inf
        assert cv2.imwrite(str(nan / f"{i}.tif"), bgr)
        Image.fromarray(np.full((48, 64), 0.3 + 0.1 * i, np.float32), mode="F").save(grey / f"{i}.tif")
    out = tmp_path / "out"
    code, output = run_colonlight("enhance", str(inputs), str(clip), "-o", str(out), *GAMMA)
    assert code == 0, output
    lines = [line for line in output.splitlines() if line.startswith(("done", "failed"))]
    assert sorted(line.split()[:2][1].rstrip(":") for line in lines) == ["a", "grey", "nan"], output
    assert "Warning" not in output and "[ERROR" not in output and "imdecode" not in output, output
    for name in ("nan", "grey"):
        assert len(list((out / name / "frames").glob("*.png"))) == 3


def test_a_camera_file_in_other_digits_is_one_line_before_any_work(clip: Path, tmp_path: Path) -> None:
    camera = tmp_path / "cameras.txt"
    camera.write_text("1 PINHOLE ٦٤ ٤٨ 50 50 32 24\n", encoding="utf-8")  # 64 48 in Arabic-Indic digits
    out = tmp_path / "out"
    code, output = run_colonlight("enhance", str(clip), "-o", str(out), "--camera", str(camera), *GAMMA)
    assert code == 2, output
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(f"error: {camera}: not a valid COLMAP cameras.txt"), output
    assert not (out / "a").exists()
