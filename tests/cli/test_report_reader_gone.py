"""A report whose reader goes away (``colonlight enhance DIR 2>&1 | head -1``, a pager quit early).

Defect found: rich's console ends the process on a broken pipe (SystemExit 1) from inside whatever printed, so a
batch stopped between two clips, silently, with the rest undone. Now the report stops and the work goes on: every
clip is enhanced and the exit code is the batch's.
"""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

from ..commands import PLAIN_CONSOLE, colonlight_command, colonlight_env
from ..media import make_clip, needs_ffmpeg

pytestmark = needs_ffmpeg


def test_a_batch_whose_report_pipe_closes_enhances_every_clip(tmp_path: Path) -> None:
    clips = tmp_path / "clips"
    clips.mkdir()
    for i in range(6):
        make_clip(clips / f"c{i}.mp4", 24, 25)
    proc = subprocess.Popen(
        colonlight_command("enhance", clips, "-o", tmp_path / "out", "-m", "none"),
        env={**colonlight_env(), **PLAIN_CONSOLE},
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    assert proc.stdout is not None
    first = proc.stdout.readline().decode()
    proc.stdout.close()  # as `| head -1` does: the next line the command writes meets a closed pipe
    assert proc.wait(120) == 0, first
    assert first.startswith("done    c"), first
    manifest = json.loads((tmp_path / "out" / "manifest.json").read_text())
    assert [c["status"] for c in manifest["clips"]] == ["done"] * 6, manifest
    assert all((tmp_path / "out" / f"c{i}" / "gammas.json").is_file() for i in range(6))
