"""Paths that read like the terminal's markup (``w[/]x[bold]``: a folder ``w[`` holding ``]x[bold]``) are shown as
they are by every command that names them, never parsed: ``[/]`` closing nothing was a MarkupError traceback
(synth, content, stream, demo, an evaluate clip that failed), ``[bold]`` vanished from a name, and a line that
escaped a name which ``error_line`` escapes again showed a stray backslash."""

from __future__ import annotations

from pathlib import Path

import pytest

from ..commands import invoke_cli as invoke
from ..commands import run_colonlight
from ..media import make_clip, text_file

TINY_CLIPS = ("--frames", "4", "--width", "32", "--height", "32", "--no-video")


@pytest.fixture
def here(tmp_path: Path) -> Path:
    """A working folder whose path holds ``[/]`` and ``[bold]``."""
    folder = tmp_path / "w[" / "]x[bold]"
    folder.mkdir(parents=True)
    return folder


def test_synth_names_its_clips_and_a_blocked_output_as_they_are(here: Path) -> None:
    code, output = invoke("synth", str(here / "clips"), *TINY_CLIPS)
    assert code == 0 and f"wrote {here}/clips/clip_00000" in output
    (here / "a[").write_text("a file where a folder goes")
    code, output = invoke("synth", str(here / "a[" / "]b"), *TINY_CLIPS)
    assert code == 1 and f"error: {here}/a[/]b: cannot write the clips" in output


def test_content_names_its_clip_and_mask_as_they_are(here: Path) -> None:
    clip = make_clip(here / "c[bold].mp4", n_frames=6)
    mask = here / "m[red].pgm"
    code, output = invoke("content", str(clip), "-o", str(mask))
    assert code == 0, output
    assert f"{clip}: " in output and f"wrote {mask}" in output and mask.is_file()


def test_evaluate_names_a_failed_clip_under_such_a_folder(here: Path) -> None:
    make_clip(here / "clips" / "good.mp4", n_frames=8)
    bad = text_file(here / "clips" / "bad[red].mp4")
    code, output = invoke("evaluate", str(here / "clips"), "-o", str(here / "report"), "-m", "none", "--no-colmap")
    assert code == 1, output  # a clip failed: the report is written all the same
    assert f"failed  {bad}: not a video" in output
    assert f"report: {here}/report/report.html" in output


def test_stream_names_its_source_and_outputs_as_they_are(here: Path) -> None:
    clip = make_clip(here / "c[bold].mp4", n_frames=6)
    out = here / "live[/]"
    code, output = run_colonlight("stream", str(clip), "-o", str(out))
    assert code == 0, output
    assert f"{clip}: waiting for frames" in output and f"outputs: {out}" in output


def test_demo_names_its_outputs_as_they_are(here: Path) -> None:
    code, output = run_colonlight("demo", "-o", str(here / "demo"), "--frames", "10", "-q")
    assert code == 0, output
    assert f"manifest        {here}/demo/enhanced/manifest.json" in output
