"""Memory is bounded by the frame size, never by the input: repeated frames stream one at a time.

A source frame that the fps conversion repeats (a timestamp gap, a slow source, a high --fps) used to be copied
for every repeat before the first was handed on: a 4-frame 720p clip with a 60 s gap peaked at 3.3 GB. These
tests run real clips with long gaps through the decoder and through a real ``colonlight enhance`` process and
hold the peak to the bound that ``colonlight.pipeline.peak_rss_bound`` writes down.
"""

from __future__ import annotations

import subprocess
import sys
import tracemalloc
from fractions import Fraction
from pathlib import Path

import pytest

from colonlight.pipeline import peak_rss_bound
from colonlight.video import FpsRun, FpsSelector, iter_video_frames

from ...commands import colonlight_command
from ...media import ffmpeg_fps_indices, make_vfr_clip, needs_ffmpeg, read_index


def run_measured(cmd: list[str], timeout: float = 300) -> tuple[int, str, int]:
    """Run ``cmd``; return its exit code, its stderr and its peak resident memory in bytes (``wait4``'s
    ``ru_maxrss``: the largest of the process and the children it waited for)."""
    # Linux carries a process's peak RSS across exec: a child forked from this (large, torch-laden) pytest process
    # would report pytest's size, not its own. A tiny launcher forks the command and reports the command's peak.
    launcher = (
        "import os, subprocess, sys\n"
        "p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
        "_, status, usage = os.wait4(p.pid, 0)\n"
        "sys.stdout.write(f'{os.waitstatus_to_exitcode(status)} {usage.ru_maxrss}')\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", launcher, *cmd], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        stdout, stderr = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise
    code, maxrss_kib = (int(x) for x in stdout.split())
    return code, stderr.decode(errors="replace"), maxrss_kib * 1024


def test_a_gap_of_an_hour_is_one_run() -> None:
    sel = FpsSelector(18, Fraction(1, 1000))
    runs = sel.push_runs(0) + sel.push_runs(40) + sel.push_runs(3_600_040) + sel.close_runs(3_600_100)
    assert runs == [FpsRun(0, 0, 0, 1), FpsRun(1, 1, 1, 64800), FpsRun(64801, 2, 64801, 1)]
    expanded = [d for r in runs for d in r.decisions()]
    assert [d.index for d in expanded] == list(range(64802)) and expanded[-1].source_index == 2


@needs_ffmpeg
def test_repeats_of_a_long_gap_are_handed_out_one_at_a_time(tmp_path: Path) -> None:
    # 320x240 and a 30 s gap: 540 repeats of frame 1, 230 kB each (124 MB if they were all held)
    clip = make_vfr_clip(tmp_path / "gap.mkv", [0.0, 0.05, 30.0, 30.05], size=(320, 240))
    frame_bytes = 320 * 240 * 3
    tracemalloc.start()
    try:
        sources = []
        for f in iter_video_frames(clip, 18):
            sources.append(f.source_index)
            f.image[:] = 0  # a caller may change a frame in place: the next repeat must not see it
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert len(sources) > 540 and sources.count(1) >= 530
    assert peak < 12 * frame_bytes, f"peak {peak / 1e6:.1f} MB while streaming repeats"


@needs_ffmpeg
def test_repeats_are_pristine_copies_that_match_ffmpeg(tmp_path: Path) -> None:
    clip = make_vfr_clip(tmp_path / "gap.mp4", [0.0, 0.04, 3.0, 3.04, 3.08])
    ours = []
    for f in iter_video_frames(clip, 18):
        ours.append(read_index(f.image))
        f.image[:] = 255  # spoiling the frame handed out must not spoil the next copy
    assert ours == ffmpeg_fps_indices(clip, 18)


@needs_ffmpeg
@pytest.mark.timeout(600)
def test_cli_peak_memory_on_a_long_gap_stays_within_the_written_bound(tmp_path: Path) -> None:
    """A real `colonlight enhance` (frames and enhanced.mp4) on a 4-frame 720p clip with a 12 s timestamp gap:
    216 output frames of 2.8 MB. Holding the repeats (the old way) needs ~0.9 GB and breaks the bound."""
    width, height = 1280, 720
    clip = make_vfr_clip(tmp_path / "gap.mp4", [0.0, 0.05, 12.0, 12.05], size=(width, height))
    out = tmp_path / "out"
    cmd = colonlight_command("enhance", clip, "-o", out, "--method", "none", "-f", "jpg", "--video", "-q")
    code, stderr, peak = run_measured(cmd)
    assert code == 0, stderr
    frames = sorted((out / "gap" / "frames").glob("*.jpg"))
    assert len(frames) == len(ffmpeg_fps_indices(clip, 18)) >= 216
    bound = peak_rss_bound(width, height, workers=1, video=True)
    assert peak <= bound, f"peak RSS {peak / 2**20:.0f} MiB > bound {bound / 2**20:.0f} MiB"
    # the bound catches the old way: the repeats alone exceed all it allows for frames
    held_all = len(frames) * width * height * 3
    assert held_all > bound - peak_rss_bound(0, 0, video=True)


def test_the_bound_grows_with_frame_size_and_workers_only() -> None:
    small, big = peak_rss_bound(320, 240), peak_rss_bound(1920, 1080)
    assert small < big
    assert peak_rss_bound(1920, 1080, workers=2) > 2 * (big - peak_rss_bound(0, 0))
    assert peak_rss_bound(1920, 1080, video=True) > big
